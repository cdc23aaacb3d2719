use glam::Vec3;
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_tree::{Frame, FrameTopology};

use crate::{Hints, LeafLayout, MeshView, Plausibility, PlausibilityOptions, read_glb};

/// A closed tube of `sides` sides and radius `r` from `a` up to `b`
/// (vertical axis), appended to `positions`/`indices`.
fn tube(positions: &mut Vec<Vec3>, indices: &mut Vec<u32>, a: Vec3, b: Vec3, r: f32) {
    let sides = 8u32;
    let base = positions.len() as u32;
    for end in [a, b] {
        for j in 0..sides {
            let t = j as f32 / sides as f32 * std::f32::consts::TAU;
            positions.push(end + Vec3::new(t.cos(), 0.0, t.sin()) * r);
        }
    }
    for j in 0..sides {
        let (p, q) = (base + j, base + (j + 1) % sides);
        indices.extend_from_slice(&[p, q, q + sides, p, q + sides, p + sides]);
    }
    // Caps.
    positions.extend([a, b]);
    let (ca, cb) = (base + 2 * sides, base + 2 * sides + 1);
    for j in 0..sides {
        let (p, q) = (base + j, base + (j + 1) % sides);
        indices.extend_from_slice(&[q, p, ca, p + sides, q + sides, cb]);
    }
}

/// A square leaf of side `s` whose base corner sits at `at`, in the XY plane.
fn leaf(positions: &mut Vec<Vec3>, indices: &mut Vec<u32>, at: Vec3, s: f32) {
    let base = positions.len() as u32;
    positions.extend([
        at,
        at + Vec3::X * s,
        at + Vec3::new(s, s, 0.0),
        at + Vec3::Y * s,
    ]);
    indices.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
}

struct Scene {
    bp: Vec<Vec3>,
    bi: Vec<u32>,
    lp: Vec<Vec3>,
    li: Vec<u32>,
}

impl Scene {
    /// A 10 m trunk of radius 0.2 m.
    fn trunk() -> Scene {
        let (mut bp, mut bi) = (Vec::new(), Vec::new());
        tube(&mut bp, &mut bi, Vec3::ZERO, Vec3::Y * 10.0, 0.2);
        Scene::of(bp, bi)
    }

    /// Branches only.
    fn of(bp: Vec<Vec3>, bi: Vec<u32>) -> Scene {
        Scene {
            bp,
            bi,
            lp: Vec::new(),
            li: Vec::new(),
        }
    }

    fn view(&self) -> MeshView<'_> {
        MeshView {
            branch_positions: &self.bp,
            branch_indices: &self.bi,
            leaf_positions: &self.lp,
            leaf_indices: &self.li,
            leaves: LeafLayout::Uniform {
                vertices_per_leaf: 4,
            },
        }
    }
}

#[test]
fn a_leaf_on_the_tube_does_not_float() {
    let mut s = Scene::trunk();
    leaf(&mut s.lp, &mut s.li, Vec3::new(0.2, 5.0, 0.0), 0.1);
    let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
    assert_eq!((r.leaves, r.floating_leaves, r.worst_leaf_gap), (1, 0, 0.0));
    assert_eq!((r.branch_pieces, r.floating_branches), (1, 0));
    assert_eq!(r.height, 10.0);
}

#[test]
fn the_same_leaf_moved_away_floats_by_its_exact_gap() {
    let mut s = Scene::trunk();
    // Allowed: half the leaf's size (its diagonal, 0.1·√2) plus 0.5 % of 10 m.
    let allowed = 0.05 * 2f32.sqrt() + 0.05;
    for (dx, floats) in [(allowed - 0.01, false), (allowed + 0.01, true), (1.0, true)] {
        s.lp.clear();
        s.li.clear();
        leaf(&mut s.lp, &mut s.li, Vec3::new(0.2 + dx, 5.0, 0.0), 0.1);
        let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
        assert_eq!(r.floating_leaves, u32::from(floats), "dx {dx}");
        if floats {
            // The tube is an octagon: its flat face at angle 0 is a vertex,
            // so the nearest point is that vertex column.
            assert!(
                (r.worst_leaf_gap - dx).abs() < 1e-4,
                "{} vs {dx}",
                r.worst_leaf_gap
            );
            assert_eq!(r.floating[0].leaf, 0);
            assert!((r.floating[0].allowed - allowed).abs() < 1e-5);
        }
    }
    // Without exact gaps: the count, no distance.
    let opts = PlausibilityOptions::default().with_exact_gaps(false);
    let r = Plausibility::of(&s.view(), &opts).unwrap();
    assert_eq!(r.floating_leaves, 1);
    assert!(r.worst_leaf_gap.is_nan());
}

#[test]
fn zero_size_leaves_are_skipped() {
    let mut s = Scene::trunk();
    leaf(&mut s.lp, &mut s.li, Vec3::new(3.0, 5.0, 0.0), 0.0);
    let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
    assert_eq!((r.leaves, r.floating_leaves), (0, 0));
}

#[test]
fn two_tubes_apart_give_one_floating_piece() {
    let mut s = Scene::trunk();
    // 0.5 m from the trunk's surface: beyond 2 % of 10 m.
    tube(
        &mut s.bp,
        &mut s.bi,
        Vec3::new(0.8, 4.0, 0.0),
        Vec3::new(0.8, 6.0, 0.0),
        0.1,
    );
    let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
    assert_eq!((r.branch_pieces, r.floating_branches), (2, 1));
    let f = r.floating_pieces[0];
    assert_eq!(f.first_vertex, 18);
    assert!((f.lowest.y - 4.0).abs() < 1e-6);
    // 0.15 m away: within the reach.
    let mut s = Scene::trunk();
    tube(
        &mut s.bp,
        &mut s.bi,
        Vec3::new(0.45, 4.0, 0.0),
        Vec3::new(0.45, 6.0, 0.0),
        0.1,
    );
    let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
    assert_eq!(r.floating_branches, 0);
}

#[test]
fn the_root_piece_is_exempt() {
    // The lower piece is the root even though it is the smaller one.
    let (mut bp, mut bi) = (Vec::new(), Vec::new());
    tube(
        &mut bp,
        &mut bi,
        Vec3::new(5.0, 2.0, 0.0),
        Vec3::new(5.0, 10.0, 0.0),
        0.2,
    );
    tube(&mut bp, &mut bi, Vec3::ZERO, Vec3::Y, 0.1);
    let s = Scene::of(bp, bi);
    let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
    assert_eq!((r.branch_pieces, r.floating_branches), (2, 1));
    assert_eq!(r.floating_pieces[0].first_vertex, 0);
}

#[test]
fn a_child_tube_starting_inside_its_parent_is_attached() {
    // A thick trunk (radius 0.5 m, 5 % of the height) and a twig whose
    // first ring sits on its axis: the surfaces cross where the twig leaves
    // the trunk, though every twig vertex is far from the trunk's surface.
    let (mut bp, mut bi) = (Vec::new(), Vec::new());
    tube(&mut bp, &mut bi, Vec3::ZERO, Vec3::Y * 10.0, 0.5);
    let (a, b) = (Vec3::Y * 5.0, Vec3::new(3.0, 8.0, 0.0));
    let base = bp.len() as u32;
    tube(&mut bp, &mut bi, Vec3::ZERO, Vec3::Y, 0.05);
    // Shear the twig's unit tube onto a → b.
    for p in &mut bp[base as usize..] {
        *p = a + (b - a) * p.y + Vec3::new(p.x, 0.0, p.z);
    }
    let s = Scene::of(bp, bi);
    let r = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap();
    assert_eq!((r.branch_pieces, r.floating_branches), (2, 0));
}

#[test]
fn bad_input_is_the_callers_mistake() {
    let mut s = Scene::trunk();
    s.bi.push(999);
    s.bi.push(0);
    s.bi.push(0);
    let e = Plausibility::of(&s.view(), &PlausibilityOptions::default()).unwrap_err();
    assert_eq!(
        e,
        crate::VerifyError::IndexOutOfRange {
            mesh: "branch",
            index: 999,
            vertices: 18
        }
    );
}

#[test]
fn in_process_and_read_back_agree_on_our_frames() {
    let tree = treemorph_gltf::sample::sample_tree(200);
    let topology = FrameTopology::of_tree(&tree);
    let mut frame = Frame::of_tree(&tree);
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    let mut check = Plausibility::new();
    let opts = PlausibilityOptions::default();
    let glb = writer.write(&frame).unwrap();
    let a = check
        .check(&MeshView::of_frame_meshes(writer.meshes()), &opts)
        .unwrap();
    let meshes = read_glb(&glb).unwrap();
    let b = Plausibility::of(&meshes.view(), &opts).unwrap();
    assert!(a.leaves > 100, "{a:?}");
    assert_eq!(a.floating_leaves, 0, "{a:?}");
    assert_eq!((b.leaves, b.floating_leaves), (a.leaves, 0));
    assert_eq!(
        (b.branch_pieces, b.floating_branches),
        (a.branch_pieces, a.floating_branches)
    );
    // Push every leaf 1 m sideways: all float, in both.
    for l in &mut frame.leaves {
        l.anchor += Vec3::X * 50.0;
    }
    let glb = writer.write(&frame).unwrap();
    let a = check
        .check(&MeshView::of_frame_meshes(writer.meshes()), &opts)
        .unwrap();
    let b = Plausibility::of(&read_glb(&glb).unwrap().view(), &opts).unwrap();
    assert_eq!(a.floating_leaves, a.leaves);
    assert_eq!(b.floating_leaves, b.leaves);
    assert!((a.worst_leaf_gap - b.worst_leaf_gap).abs() < 1e-4);
}

/// The trunk and a side tube at `x`, with the same index buffer whatever `x`.
fn trunk_and_tube(x: f32) -> Scene {
    let mut s = Scene::trunk();
    tube(
        &mut s.bp,
        &mut s.bi,
        Vec3::new(x, 4.0, 0.0),
        Vec3::new(x, 6.0, 0.0),
        0.1,
    );
    s
}

#[test]
fn a_proof_kept_from_the_last_frame_is_retested() {
    // Near, then moved away, then back: one context, as over a sequence.
    let mut check = Plausibility::new();
    let opts = PlausibilityOptions::default();
    for (x, floats) in [(0.45, 0), (0.8, 1), (0.45, 0), (0.25, 0), (0.8, 1)] {
        let s = trunk_and_tube(x);
        let r = check.check(&s.view(), &opts).unwrap();
        let reference = Plausibility::new()
            .check_reference(&s.view(), &opts)
            .unwrap();
        assert_eq!(r.floating_branches, floats, "x {x}");
        assert_eq!(r, reference, "x {x}");
    }
}

#[test]
fn the_fast_check_agrees_with_the_reference_over_a_sequence() {
    fast_and_reference_over_a_sequence(false);
}

#[test]
fn pieces_out_of_order_in_the_index_buffer_check_alike() {
    // Files from other tools need not list a tube's triangles together or
    // in order: the same frames with the triangles reversed.
    fast_and_reference_over_a_sequence(true);
}

/// Scatters a sample tree a little more each frame, so leaves come loose
/// one after another, and checks every frame with one fast context (as
/// over a job's sequence), with one that also has the writer's hints (as
/// a job's has), and with the reference: equal reports. With `reversed`,
/// the branch triangles are listed last first.
fn fast_and_reference_over_a_sequence(reversed: bool) {
    let tree = treemorph_gltf::sample::sample_tree(400);
    let topology = FrameTopology::of_tree(&tree);
    let mut frame = Frame::of_tree(&tree);
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    let (mut fast, mut reference) = (Plausibility::new(), Plausibility::new());
    let mut hinted = Plausibility::new();
    hinted.set_hints(Hints::of_tubes(
        &topology,
        &writer.meshes().branches().vertex_owners(),
    ));
    let opts = PlausibilityOptions::default();
    let base = frame.clone();
    for step in 0..6 {
        let k = step as f32 * 0.15;
        for (i, (p, q)) in frame.positions.iter_mut().zip(&base.positions).enumerate() {
            let h = (i as f32 * 12.9898).sin() * 43_758.547;
            let d = Vec3::new(h.fract(), (h * 1.7).fract(), (h * 2.3).fract()) - 0.5;
            *p = *q + d * k;
        }
        for (i, (l, m)) in frame.leaves.iter_mut().zip(&base.leaves).enumerate() {
            l.anchor = m.anchor + Vec3::X * (k * (i % 3) as f32);
        }
        writer.write(&frame).unwrap();
        let mut view = MeshView::of_frame_meshes(writer.meshes());
        let reversed_indices: Vec<u32> = view
            .branch_indices
            .chunks_exact(3)
            .rev()
            .flatten()
            .copied()
            .collect();
        if reversed {
            view.branch_indices = &reversed_indices;
        }
        let a = fast.check(&view, &opts).unwrap();
        let b = reference.check_reference(&view, &opts).unwrap();
        assert_eq!(a, b, "step {step}");
        assert_eq!(
            hinted.check(&view, &opts).unwrap(),
            b,
            "step {step}, hinted"
        );
        if step == 5 {
            assert!(a.floating_leaves > 0);
        }
    }
}

/// A generated maple's topology and first frame, with the leaves that
/// `moved` picks (from the leaf count) moved `away`.
fn maple_with_leaves_moved(
    (seed, size): (u64, u32),
    moved: impl Fn(usize) -> Vec<usize>,
    away: Vec3,
) -> (FrameTopology, Frame, Vec<usize>) {
    let tree = treemorph_generate::generate(
        &treemorph_generate::GenerateOptions::new(treemorph_generate::Preset::Maple, seed)
            .with_size(size),
    )
    .unwrap();
    let topology = FrameTopology::of_tree(&tree);
    let mut frame = Frame::of_tree(&tree);
    let moved = moved(frame.leaves.len());
    for &i in &moved {
        frame.leaves[i].anchor += away;
    }
    (topology, frame, moved)
}

/// A frame GLB writer that has written `frame`.
fn written(topology: &FrameTopology, frame: &Frame) -> FrameGlbWriter {
    let mut writer =
        FrameGlbWriter::new(topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    writer.write(frame).unwrap();
    writer
}

#[test]
fn a_first_frame_searched_in_halves_names_its_floating_leaves() {
    // Thousands of open leaves (a fresh context has every leaf open) are
    // searched on two threads: leaves moved away in either half must come
    // back as themselves, in order.
    let split = |n: usize| {
        assert!(n >= 2_048, "{n} leaves: too few to split");
        vec![3, n / 2 - 1, n / 2 + 5, n - 2]
    };
    let (topology, frame, moved) =
        maple_with_leaves_moved((1, 2_000), split, Vec3::new(50.0, 0.0, 0.0));
    let writer = written(&topology, &frame);
    let view = MeshView::of_frame_meshes(writer.meshes());
    let report = Plausibility::new()
        .check(&view, &PlausibilityOptions::default())
        .unwrap();
    let floating: Vec<usize> = report.floating.iter().map(|f| f.leaf as usize).collect();
    assert_eq!(floating, moved);
}

/// A first frame (every leaf and tube without a proof) checked with the
/// writer's hints, with hints that name the wrong tubes, and without
/// any: the same report as the reference's, floating leaves and a
/// floating tube included. Hints only order the search.
#[test]
fn hints_right_or_wrong_leave_a_first_frames_report_as_it_is() {
    let three = |n: usize| vec![0, n / 3, n - 1];
    let (topology, frame, _) = maple_with_leaves_moved((2, 1_500), three, Vec3::X * 40.0);
    let n = frame.leaves.len();
    let writer = written(&topology, &frame);
    let owners = writer.meshes().branches().vertex_owners();
    // The last tube's vertices, moved away in the mesh: a floating tube.
    let mut branch_positions = writer.meshes().branches().buffers().positions.clone();
    let last = owners.last().unwrap().0;
    for (p, &(strand, _)) in branch_positions.iter_mut().zip(&owners) {
        if strand == last {
            *p += Vec3::new(0.0, 0.0, 30.0);
        }
    }
    let view = MeshView {
        branch_positions: &branch_positions,
        ..MeshView::of_frame_meshes(writer.meshes())
    };
    let opts = PlausibilityOptions::default();
    let reference = Plausibility::new().check_reference(&view, &opts).unwrap();
    assert!(
        reference.floating_leaves >= 3,
        "{}",
        reference.floating_leaves
    );
    assert!(reference.floating_branches >= 1);

    let right = Hints::of_tubes(&topology, &owners);
    let rotate = |v: &mut u32, by: u32| *v = (*v + by) % view.branch_positions.len() as u32;
    let mut wrong = right.clone();
    wrong.leaf_hosts.iter_mut().for_each(|v| rotate(v, 977));
    wrong
        .tube_hosts
        .iter_mut()
        .for_each(|(_, h)| rotate(h, 1_531));
    wrong.leaf_hosts.truncate(n / 2);
    for hints in [None, Some(right), Some(wrong)] {
        let mut check = Plausibility::new();
        if let Some(h) = hints.clone() {
            check.set_hints(h);
        }
        let report = check.check(&view, &opts).unwrap();
        assert_eq!(
            report,
            reference,
            "hints {:?}",
            hints.map(|h| h.leaf_hosts.len())
        );
    }
}

/// A context that checked another sequence, then starts a new one with
/// the writer's hints, reports that sequence's first frames as a new
/// context does: kept proofs of other meshes or of the same meshes at
/// another instant are forgotten, and kept labels are checked against
/// the new index buffers.
#[test]
fn a_context_started_again_reports_as_a_new_one() {
    let three = |n: usize| vec![0, n / 3, n - 1];
    let (topology, frame, _) = maple_with_leaves_moved((2, 1_500), three, Vec3::X * 40.0);
    let writer = written(&topology, &frame);
    let hints = || Hints::of_tubes(&topology, &writer.meshes().branches().vertex_owners());
    let view = MeshView::of_frame_meshes(writer.meshes());
    let opts = PlausibilityOptions::default();
    let mut fresh = Plausibility::new();
    fresh.set_hints(hints());
    let expected = fresh.check(&view, &opts).unwrap();
    assert!(
        expected.floating_leaves >= 3,
        "{}",
        expected.floating_leaves
    );

    // Another tree's frames, then this tree's with its leaves in place.
    let other = Scene::trunk();
    let (settled, settled_frame, _) =
        maple_with_leaves_moved((2, 1_500), |_| Vec::new(), Vec3::ZERO);
    let settled_writer = written(&settled, &settled_frame);
    let settled_view = MeshView::of_frame_meshes(settled_writer.meshes());
    let mut kept = Plausibility::new();
    kept.check(&other.view(), &opts).unwrap();
    let mut first = |v: &MeshView<'_>| {
        kept.start_sequence(hints());
        kept.check(v, &opts).unwrap()
    };
    assert_eq!(first(&view), expected, "after other meshes");
    assert_eq!(first(&settled_view).floating_leaves, 0);
    assert_eq!(first(&view), expected, "after the same meshes");
    // The proofs of that first frame (three leaves without one) are taken
    // up by the next sequence's first frame, which has them all in place.
    assert_eq!(first(&settled_view).floating_leaves, 0);
    assert_eq!(first(&view), expected, "again");
}
