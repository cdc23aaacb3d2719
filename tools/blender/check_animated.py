"""Checks that Blender's own glTF importer plays an animated GLB as treemorph wrote it.

    python check_animated.py FILE.glb EXPECTED.json [--tolerance X]

(run with the python of a venv that has the `bpy` module, see README.md).
The Blender counterpart of tools/render/check-animated.mjs, reading the
same EXPECTED.json:

    { "tolerance": 1e-4,
      "meshes": [ { "name": "leaves", "vertices": 1234, "morphTargets": 5,
                    "samples": [ { "time": 0.5, "indices": [0, 17],
                                   "positions": [[x, y, z], [x, y, z]] } ] } ] }

It imports FILE.glb with bpy.ops.import_scene.gltf into an empty scene
(factory settings, default import options), then for every sample time sets
the scene to that time, lets Blender evaluate everything (shape keys, object
and parent transforms, Armature modifiers) and compares the evaluated mesh's
world-space vertices with the expected positions. Because it reads evaluated
geometry it checks morph-target, transform and skinned animation alike.

Why it works the way it does:

* Nearest-vertex matching. The importer does not keep glTF vertex indices: it
  builds one Blender mesh per glTF mesh by concatenating the primitives,
  keeping per primitive only the vertices its indices use, and may merge
  or reorder them. So an expected position is not looked up by index; the
  error is its distance to the nearest evaluated vertex of that node's
  objects (a KD-tree over all of them). A wrong animation still shows up:
  at a time where the shape is wrong, the expected positions lie off the
  evaluated surface's vertices by about as much as the shape is off.

* Axes. glTF is Y-up, Blender Z-up; the importer always converts
  (x, y, z)_gltf -> (x, -z, y)_blender (it has no option to keep Y-up, only
  an undocumented debug switch, bpy.app.debug_value = 100), so evaluated
  positions are converted back with (x, y, z)_blender -> (x, z, -y)_gltf.
  The scene's unit scale stays 1 in factory settings, so lengths are kept.

* Time. The importer puts a glTF key at time t on frame t * fps (so t = 0
  is frame 0, not the scene's start frame 1) with the scene's frame rate,
  24 in factory settings, which it leaves alone. (It multiplies by
  fps * fps_base where playback uses fps / fps_base; the two agree because
  fps_base is 1 in factory settings.) A sample time t is therefore shown at
  frame t * fps / fps_base, usually not a whole frame, so the scene is set
  with frame_set(frame, subframe=fraction). Blender holds the first and last
  keys' values outside the keyed range, as the three.js checker's clamped,
  play-once action does.

* Which animation. The importer stashes every glTF animation as a muted NLA
  track and makes the first one the active action of each animated
  datablock (shape keys, objects, armatures), so what Blender evaluates is
  the file's first animation, like the three.js checker.

* Known differences from the glTF spec that this check will report, not
  hide: Blender interpolates a LINEAR rotation channel component-wise on
  the quaternion and normalises (nlerp), not by slerp, so between two keys
  that turn by a large angle a bone or node lags or leads (at most 0.92
  degrees for keys 90 degrees apart, 0.033 for 30, 0.0012 for 10). And
  Blender clamps shape key values to their slider range, which the importer
  widens beyond [0, 1] only as far as each target's first key's weight.

Prints the import time, one line per mesh and `MISMATCH` lines (first 20),
and exits 1 on any mismatch or import failure, 2 on bad usage.
"""

import argparse
import contextlib
import io
import json
import math
import os
import re
import sys
import time

import bpy
from mathutils import Vector
from mathutils.kdtree import KDTree

MAX_MISMATCH_LINES = 20


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog='check_animated.py',
        description="Checks that Blender's glTF importer plays an animated GLB as expected.")
    parser.add_argument('file', metavar='FILE.glb')
    parser.add_argument('expected', metavar='EXPECTED.json')
    parser.add_argument('--tolerance', type=float,
                        help="override EXPECTED.json's tolerance for this file")
    return parser.parse_args(argv[1:])  # exits 2 on bad usage


def load_expected(path):
    with open(path, encoding='utf-8') as f:
        expected = json.load(f)
    if not isinstance(expected.get('meshes'), list):
        raise ValueError(path + ': no "meshes" list')
    return expected


def import_glb(path):
    """Imports `path` into an empty scene and returns the import time in ms.

    The importer logs INFO lines to stdout; they are kept out of this
    checker's output and shown on stderr only if the import fails."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    log = io.StringIO()
    start = time.perf_counter()
    try:
        with contextlib.redirect_stdout(log):
            result = bpy.ops.import_scene.gltf(filepath=path)
    except RuntimeError as e:
        sys.stderr.write(log.getvalue())
        # Blender puts "Error: " in front of the importer's message.
        raise RuntimeError(str(e).strip().removeprefix('Error: ')) from None
    if 'FINISHED' not in result:
        sys.stderr.write(log.getvalue())
        raise RuntimeError('the importer returned ' + ', '.join(sorted(result)))
    return (time.perf_counter() - start) * 1000


def with_suffixes(name, objects):
    """Objects named `name` or, when that name was taken, `name.001` etc."""
    pattern = re.compile(re.escape(name) + r'(\.\d{3,})?')
    return [o for o in objects if pattern.fullmatch(o.name)]


def mesh_objects_for(name):
    """The Blender mesh objects that show the glTF node `name`.

    Usually the node becomes one object of that name holding all the glTF
    mesh's primitives (one material slot per material). But Blender allows
    only one kind of data per object, so the importer moves a mesh onto a
    new child object when the node is also a bone or an armature, and it
    moves a skinned mesh under the armature that skins it -- onto a new
    object named after the glTF *mesh* when the node itself is animated or
    has children. Names are unique in Blender, so a name already taken gets
    a `.001` suffix. Hence: objects with the node's name and their mesh
    descendants; failing that, mesh objects whose mesh data has that name
    (treemorph names each mesh after its node)."""
    found = []
    for obj in with_suffixes(name, bpy.data.objects):
        for o in [obj, *obj.children_recursive]:
            if o.type == 'MESH' and o not in found:
                found.append(o)
    if not found:
        meshes = set(with_suffixes(name, bpy.data.meshes))
        found = [o for o in bpy.data.objects if o.type == 'MESH' and o.data in meshes]
    return found


def active_action(datablock):
    data = getattr(datablock, 'animation_data', None)
    return data.action if data and data.action else None


def movers(obj):
    """The objects whose animation can move `obj`'s vertices: itself, its
    parents, and the armatures of its Armature modifiers (and their parents)."""
    found = []
    todo = [obj]
    while todo:
        o = todo.pop(0)
        if o in found:
            continue
        found.append(o)
        if o.parent:
            todo.append(o.parent)
        todo.extend(m.object for m in o.modifiers if m.type == 'ARMATURE' and m.object)
    return found


def describe_actions(objects):
    """Names the active actions that animate these mesh objects: on their
    shape keys, or on an object or armature that moves them."""
    found = []

    def add(datablock, what):
        action = active_action(datablock)
        if action and (action.name, what) not in found:
            found.append((action.name, what))

    for obj in objects:
        if obj.data.shape_keys:
            add(obj.data.shape_keys, 'shape keys')
        for o in movers(obj):
            add(o, ('armature ' if o.type == 'ARMATURE' else 'object ') + o.name)
    if not found:
        return 'none'
    return ', '.join(f'{name} ({what})' for name, what in found)


def shape_key_count(obj):
    key = obj.data.shape_keys
    if not key:
        return 0
    return sum(1 for block in key.key_blocks if block != key.reference_key)


def skinned_by(obj):
    return [m.object.name for m in obj.modifiers if m.type == 'ARMATURE' and m.object]


def set_time(scene, seconds):
    """Shows the animation at `seconds`: the importer keyed glTF time t on
    frame t * fps, and Blender plays fps / fps_base frames a second."""
    frame = seconds * scene.render.fps / scene.render.fps_base
    whole = math.floor(frame)
    scene.frame_set(whole, subframe=frame - whole)


def gltf_from_blender(v):
    """Undoes the importer's Y-up to Z-up conversion."""
    return Vector((v.x, v.z, -v.y))


def evaluated_positions(objects):
    """World-space positions, in glTF axes, of the evaluated (animated,
    deformed) vertices of `objects` at the scene's current time."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    positions = []
    for obj in objects:
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            world = evaluated.matrix_world
            positions.extend(gltf_from_blender(world @ v.co) for v in mesh.vertices)
        finally:
            evaluated.to_mesh_clear()
    return positions


def nearest_tree(positions):
    tree = KDTree(len(positions))
    for i, p in enumerate(positions):
        tree.insert(p, i)
    tree.balance()
    return tree


def fmt(v):
    return '(' + ', '.join(f'{c:.6g}' for c in v) + ')'


def check_mesh(scene, want, tolerance):
    """Returns (summary line, mismatch lines) for one EXPECTED.json mesh."""
    name = want['name']
    objects = mesh_objects_for(name)
    # A node drawn in pieces (`prefix`): the samples are matched against
    # every mesh object whose name starts with the prefix and that is
    # shown at the sample's time. treemorph's basis animation draws the
    # leaves that change material by nodes that switch between scale 1
    # and 0, each holding only its own leaves' vertices once imported.
    pieces = want.get('prefix')
    if pieces:
        objects = [o for o in bpy.data.objects if o.type == 'MESH' and o.name.startswith(pieces)]
    if not objects:
        return None, [f'{name}: no Blender mesh object for this node']
    errors = []
    vertices = sum(len(o.data.vertices) for o in objects)
    keys = max(shape_key_count(o) for o in objects)
    parts = [o.name for o in objects]
    where = '' if parts == [name] else ' (objects ' + ', '.join(parts) + ')'
    counts = f'{vertices} vertices'
    if 'vertices' in want and vertices != want['vertices']:
        # Not a failure by itself: the importer drops vertices that no
        # primitive's indices use. The samples below are the real test.
        counts += f' (glTF {want["vertices"]})'
    if 'morphTargets' in want and keys != want['morphTargets']:
        errors.append(f'{name}: {keys} shape keys, expected {want["morphTargets"]}')
    skins = sorted({arma for o in objects for arma in skinned_by(o)})
    skinned = ', skinned by ' + ', '.join(skins) if skins else ''

    worst, worst_time = 0.0, None
    for sample in want['samples']:
        set_time(scene, sample['time'])
        shown = [o for o in objects if abs(o.matrix_world.determinant()) > 1e-12] if pieces else objects
        positions = evaluated_positions(shown)
        if not positions:
            errors.append(f'{name}: no vertices at {sample["time"]} s')
            continue
        tree = nearest_tree(positions)
        for index, expected in zip(sample['indices'], sample['positions']):
            got, _, error = tree.find(expected)
            if worst_time is None or error > worst:
                worst, worst_time = error, sample['time']
            if not error <= tolerance:
                errors.append(f'{name} vertex {index} at {sample["time"]} s: nearest vertex '
                              f'{fmt(got)}, expected {fmt(expected)}, error {error:.3g}')
    line = (f'{name}{where}: {counts}, {keys} shape keys, action {describe_actions(objects)}'
            f'{skinned}, largest error {worst:.2e} at time {worst_time}')
    return line, errors


def describe_armatures():
    """One line per imported armature (skinned files): bones and action."""
    lines = []
    for obj in bpy.data.objects:
        if obj.type == 'ARMATURE':
            action = active_action(obj)
            skins = [o.name for o in bpy.data.objects if obj.name in
                     (skinned_by(o) if o.type == 'MESH' else [])]
            lines.append(f'armature {obj.name}: {len(obj.data.bones)} bones, action '
                         f'{action.name if action else "none"}, skins '
                         f'{", ".join(skins) or "nothing"}')
    return lines


def main(argv):
    args = parse_args(argv)
    file = args.file
    try:
        expected = load_expected(args.expected)
    except (OSError, ValueError) as e:
        print(f'check_animated: {e}', file=sys.stderr)
        return 2
    if not os.path.isfile(file):
        print(f'check_animated: {file}: no such file', file=sys.stderr)
        return 2
    tolerance = args.tolerance if args.tolerance is not None else expected.get('tolerance')
    if not isinstance(tolerance, (int, float)):
        print(f'check_animated: {args.expected}: no "tolerance", give --tolerance', file=sys.stderr)
        return 2
    try:
        ms = import_glb(file)
    except RuntimeError as e:
        print(f'{file}: MISMATCH import failed: {e}')
        print(f'check_animated: {file}: FAILED')
        return 1
    scene = bpy.context.scene
    fps = scene.render.fps / scene.render.fps_base
    print(f'{file}: imported in {ms:.0f} ms, {fps:g} fps, tolerance {tolerance:.3g}')
    for line in describe_armatures():
        print(f'{file}: {line}')
    errors = []
    for want in expected['meshes']:
        line, mesh_errors = check_mesh(scene, want, tolerance)
        if line:
            print(f'{file}: {line}')
        errors.extend(mesh_errors)
    for error in errors[:MAX_MISMATCH_LINES]:
        print(f'{file}: MISMATCH {error}')
    if len(errors) > MAX_MISMATCH_LINES:
        print(f'{file}: ... and {len(errors) - MAX_MISMATCH_LINES} more mismatches')
    print(f'check_animated: {file}: {"FAILED" if errors else "ok"}')
    return 1 if errors else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv))
