#!/usr/bin/env python3
"""Writes GLB trees made by Modular Tree's C++ core (PyPI `modular-tree`,
imported as `m_tree`; pinned in requirements.txt) into OUT_DIR, next to the
ez-tree ones of generate.mjs, for treemorph's third-party tests.

    python3 -m venv target/third-party-venv
    target/third-party-venv/bin/pip install -r tools/third-party-trees/requirements.txt
    target/third-party-venv/bin/python tools/third-party-trees/modular_tree.py OUT_DIR

m_tree gives one welded bark mesh per tree (quads), Z up, faces wound
inward, and no leaves: the Blender add-on scatters leaves on thin branches
with geometry nodes. Here the bark is triangulated, turned to glTF's Y up
and rewound outward, and leaf cards are scattered the same way: on surface
vertices of the thinnest branches (by m_tree's per-vertex `radius`), each
card's base on the bark, pointing outward (from the ring centre,
`pivot_position`) and along the branch (`direction`). Resolution is lowered
(`resolution`, `radial_n_points`) so a tree has ~70k–110k vertices rather
than ~20 M, and imports as 8,000–13,000 branches (the acceptance asks for
2,000–15,000; resolution also sets how many stems m_tree grows). Each
tree gets `NAME.glb` (meshes `branches` and `leaves`; the leaf material
is alpha-masked with a generated leaf-shaped texture) and `NAME.json`
with the generator's figures.
"""

import json
import math
import os
import struct
import sys
import zlib

import m_tree as mt
import numpy as np

# name, seed, trunk length (m), branch levels, density per level, branch
# length per level, start angle (deg), gravity strength, leaves per stem,
# leaf length (m), resolution.
TREES = [
    ("mt-broadleaf", 3, 10.0, 2, [1.0, 1.0], [None, None], None, 0.2, 4, 0.12, 0.7),
    ("mt-sparse", 5, 8.0, 2, [0.5, 0.6], [None, None], 70, 0.4, 5, 0.10, 0.9),
    ("mt-tall", 7, 16.0, 2, [0.5, 0.8], [None, None], 45, 0.1, 4, 0.15, 0.7),
    ("mt-bushy", 11, 5.0, 3, [1.0, 0.8, 0.7], [None, None, None], 60, 0.3, 2, 0.06, 0.5),
    ("mt-weeping", 13, 9.0, 2, [0.8, 0.8], [None, None], 80, 1.5, 4, 0.10, 0.82),
]


def build(seed, length, levels, density, blength, angle, gravity, res):
    trunk = mt.TrunkFunction()
    trunk.seed = seed
    trunk.length = length
    trunk.resolution = res
    trunk.start_radius = 0.03 * length
    parent = trunk
    for level in range(levels):
        b = mt.BranchFunction()
        b.seed = seed * 31 + level
        b.resolution = res
        b.distribution.density = density[level]
        if blength[level] is not None:
            b.length.set_constant_property(_constant(blength[level]))
        if angle is not None:
            b.start_angle.set_constant_property(_constant(angle))
        b.gravity.strength = gravity
        parent.add_child(b)
        parent = b
    tree = mt.Tree()
    tree.set_trunk_function(trunk)
    tree.execute_functions()
    mesher = mt.ManifoldMesher()
    mesher.radial_n_points = 5
    mesher.smooth_iterations = 0
    return mesher.mesh_tree(tree)


def _constant(v):
    c = mt.ConstantProperty()
    c.value = v
    return c


def y_up(a):
    """m_tree's Z-up (x, y, z) to glTF's Y-up (x, z, -y)."""
    return np.stack([a[:, 0], a[:, 2], -a[:, 1]], axis=1)


def bark(mesh):
    v = y_up(mesh.get_vertices().reshape(-1, 3).astype(np.float32))
    quads = mesh.get_polygons().reshape(-1, 4)
    # Rewind outward: (a, c, b), (a, d, c); drop triangles with a repeated
    # vertex (quads collapsed to triangles at branch ends).
    tris = np.concatenate([quads[:, [0, 2, 1]], quads[:, [0, 3, 2]]])
    ok = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return v, tris[ok].astype(np.uint32)


def leaves(mesh, v, per_stem, leaf_len, rng):
    radius = mesh.get_float_attribute("radius")
    stems = mesh.get_float_attribute("stem_id")
    pivot = y_up(mesh.get_vector3_attribute("pivot_position").reshape(-1, 3))
    direction = y_up(mesh.get_vector3_attribute("direction").reshape(-1, 3))
    thin = radius <= np.quantile(radius, 0.3)
    candidates = np.nonzero(thin)[0]
    count = int(per_stem * len(np.unique(stems[candidates])))
    picks = rng.choice(candidates, size=min(count, len(candidates)), replace=False)
    positions, indices = [], []
    for i, k in enumerate(picks):
        base = v[k]
        out = base - pivot[k]
        out /= max(np.linalg.norm(out), 1e-9)
        axis = out + 0.6 * direction[k] + 0.3 * np.array([0.0, 1.0, 0.0])
        axis += 0.3 * rng.normal(size=3)
        axis /= max(np.linalg.norm(axis), 1e-9)
        side = np.cross(axis, rng.normal(size=3))
        side /= max(np.linalg.norm(side), 1e-9)
        h = leaf_len * rng.uniform(0.8, 1.2)
        w = 0.5 * h
        s = side * (w / 2)
        positions += [base - s, base + s, base + s + axis * h, base - s + axis * h]
        o = 4 * i
        indices += [o, o + 1, o + 2, o, o + 2, o + 3]
    return np.array(positions, dtype=np.float32), np.array(indices, dtype=np.uint32)


def leaf_png(size=64):
    """An RGBA leaf: an ellipse blade, base on the bottom row."""
    rows = []
    for y in range(size):
        row = bytearray([0])
        for x in range(size):
            u = (x + 0.5) / size * 2 - 1
            t = 1 - (y + 0.5) / size  # 0 at the base (bottom row)
            inside = t > 0.02 and abs(u) < math.sin(math.pi * t) ** 0.8 * 0.95
            row += bytes([60, 130, 50, 255]) if inside else bytes([60, 130, 50, 0])
        rows.append(bytes(row))
    raw = b"".join(rows)

    def chunk(kind, data):
        c = struct.pack(">I", len(data)) + kind + data
        return c + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", size, size, 8, 6, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def glb(bark_v, bark_i, leaf_v, leaf_i, uv_leaf):
    chunks, views, accessors = [], [], []
    length = 0

    def view(data, target=None):
        nonlocal length
        views.append({"buffer": 0, "byteOffset": length, "byteLength": len(data), **({"target": target} if target else {})})
        pad = (4 - len(data) % 4) % 4
        chunks.append(data + b"\0" * pad)
        length += len(data) + pad
        return len(views) - 1

    def vec(a, kind):
        a = np.ascontiguousarray(a, dtype=np.float32)
        acc = {"bufferView": view(a.tobytes(), 34962), "componentType": 5126, "count": len(a), "type": kind}
        if kind == "VEC3":
            acc["min"] = a.min(0).tolist()
            acc["max"] = a.max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    def idx(a):
        a = np.ascontiguousarray(a, dtype=np.uint32).reshape(-1)
        accessors.append({"bufferView": view(a.tobytes(), 34963), "componentType": 5125, "count": len(a), "type": "SCALAR"})
        return len(accessors) - 1

    meshes = [
        {"name": "branches", "primitives": [{"attributes": {"POSITION": vec(bark_v, "VEC3")}, "indices": idx(bark_i), "material": 0}]},
        {"name": "leaves", "primitives": [{"attributes": {"POSITION": vec(leaf_v, "VEC3"), "TEXCOORD_0": vec(uv_leaf, "VEC2")}, "indices": idx(leaf_i), "material": 1}]},
    ]
    image = view(leaf_png())
    doc = {
        "asset": {"version": "2.0", "generator": "modular-tree (m_tree) via treemorph tools/third-party-trees"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "tree", "children": [1, 2]}, {"name": "branches", "mesh": 0}, {"name": "leaves", "mesh": 1}],
        "meshes": meshes,
        "materials": [
            {"name": "bark", "pbrMetallicRoughness": {"baseColorFactor": [0.4, 0.3, 0.2, 1], "metallicFactor": 0, "roughnessFactor": 0.9}},
            {"name": "leaves", "alphaMode": "MASK", "alphaCutoff": 0.5, "doubleSided": True,
             "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0, "roughnessFactor": 0.8}},
        ],
        "images": [{"bufferView": image, "mimeType": "image/png"}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}],
        "textures": [{"sampler": 0, "source": 0}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": length}],
    }
    text = json.dumps(doc).encode()
    text += b" " * ((4 - len(text) % 4) % 4)
    binary = b"".join(chunks)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(binary), 0x004E4942) + binary)


def main():
    if len(sys.argv) != 2:
        print("usage: modular_tree.py OUT_DIR", file=sys.stderr)
        sys.exit(2)
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    for name, seed, length, levels, density, blength, angle, gravity, per_stem, leaf_len, res in TREES:
        mesh = build(seed, length, levels, density, blength, angle, gravity, res)
        v, tris = bark(mesh)
        rng = np.random.default_rng(seed)
        lv, li = leaves(mesh, v, per_stem, leaf_len, rng)
        uv = np.tile(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32), (len(lv) // 4, 1))
        data = glb(v, tris, lv, li, uv)
        with open(os.path.join(out, name + ".glb"), "wb") as f:
            f.write(data)
        facts = {
            "generator": "modular-tree",
            "seed": seed,
            "stems": int(len(np.unique(mesh.get_float_attribute("stem_id")))),
            "branch_vertices": int(len(v)),
            "leaf_quads": int(len(lv) // 4),
            "leaves": int(len(lv) // 4),
        }
        with open(os.path.join(out, name + ".json"), "w") as f:
            json.dump(facts, f, indent=2)
            f.write("\n")
        print(f"{name}.glb: {len(data)} bytes, {facts['stems']} stems, {len(v)} bark vertices, {facts['leaves']} leaves", flush=True)


if __name__ == "__main__":
    main()
