//! Leaf attachment: each leaf to the nearest skeleton segment, and wood
//! grown where a leaf proves a twig was lost.
//!
//! A kd-tree (kiddo) over points sampled along every branch gives the
//! branches near a leaf's anchor; the exact closest point on those decides
//! the branch and the parameter `t`, and the offset is the anchor minus that
//! point. A leaf whose base is unknown (no texture coordinates) is tried
//! from both ends and keeps the end nearer the skeleton.
//!
//! # Grown twigs
//! Leaves grow on twigs: a leaf whose anchor lies farther from the nearest
//! branch axis than that branch's radius plus [`REACH`] times the leaf's
//! size (the larger of its width and height) has no wood under it. Such
//! leaves are common after contraction of a welded bark mesh: the proxy's
//! vertex budget collapses the thinnest twigs and spur pruning removes
//! short leaf chains, so the twigs that bore the leaves are gone. Keeping
//! the leaf's whole offset would hang it in the air (frames place a leaf at
//! its branch point plus its offset), and clamping the offset would stack
//! leaves on the bark far from where they were drawn. Instead we restore
//! the twig the leaf proves existed: a straight chain of 1–3 nodes (at most
//! [`TWIG_SEGMENT`] leaf sizes per segment) from the closest point on the
//! nearest wood to the leaf's anchor, radius tapering from the smaller of
//! the parent's radius and [`TWIG_RADIUS`] leaf sizes to half that at the
//! tip, where the leaf hangs with a zero offset. A base inside a branch
//! splits it there (closer than a quarter leaf size to a node it starts at
//! that node instead). Far leaves are handled nearest first and grown
//! twigs count as wood for the next ones, so a leaf within reach of a
//! grown twig hangs from it and one beyond grows from it: the leaves of a
//! lost twig rebuild it as one branching chain rather than a hedgehog of
//! spikes from the limb. [`ImportReport::grown_twigs`](crate::ImportReport)
//! counts the twigs grown (growing on from a grown twig's tip extends that
//! twig rather than counting a new one).

use glam::Vec3;
use treemorph_tree::{Leaf, Node};

use crate::leaves::LeafGeometry;
use crate::mesh::FxMap;
use crate::skeleton::{SegmentIndex, closest_on_segment};

/// A leaf farther than the branch radius plus this many leaf sizes from the
/// branch axis gets a grown twig.
pub(crate) const REACH: f32 = 0.5;
/// Longest segment of a grown twig, in leaf sizes.
pub(crate) const TWIG_SEGMENT: f32 = 4.0;
/// Base radius of a grown twig (when the parent is thicker), in leaf sizes.
pub(crate) const TWIG_RADIUS: f32 = 0.03;

/// The skeleton with grown twigs and the attached leaves.
pub(crate) struct Attached {
    /// Nodes; parents may follow their children (splits are appended).
    pub nodes: Vec<Node>,
    pub leaves: Vec<Leaf>,
    pub grown_twigs: usize,
}

/// A segment as it was before any split: named by its child node.
#[derive(Clone, Copy)]
struct Segment {
    node: u32,
    parent: u32,
    a: Vec3,
    b: Vec3,
    ra: f32,
    rb: f32,
}

impl Segment {
    fn of(nodes: &[Node], node: u32) -> Option<Segment> {
        let n = nodes[node as usize];
        let parent = n.parent?;
        let p = nodes[parent as usize];
        Some(Segment {
            node,
            parent,
            a: p.position,
            b: n.position,
            ra: p.radius,
            rb: n.radius,
        })
    }

    fn at(&self, s: f32) -> (Vec3, f32) {
        (self.a.lerp(self.b, s), self.ra + (self.rb - self.ra) * s)
    }
}

/// A leaf waiting for the final numbering: segment, parameter on it.
struct Pending {
    segment: Segment,
    s: f32,
    leaf: LeafGeometry,
}

/// Grown segments in a uniform grid of sample cells.
struct Grid {
    cell: f32,
    cells: FxMap<[i32; 3], Vec<u32>>,
    segments: Vec<Segment>,
}

impl Grid {
    fn key(&self, p: Vec3) -> [i32; 3] {
        (p / self.cell).floor().as_ivec3().to_array()
    }

    fn insert(&mut self, seg: Segment) {
        let id = self.segments.len() as u32;
        self.segments.push(seg);
        let k = ((seg.a.distance(seg.b) / (0.5 * self.cell)).ceil() as usize).clamp(1, 10_000);
        for j in 0..=k {
            let key = self.key(seg.a.lerp(seg.b, j as f32 / k as f32));
            let list = self.cells.entry(key).or_default();
            if list.last() != Some(&id) {
                list.push(id);
            }
        }
    }

    /// Nearest grown segment closer than `max` (searched up to two cells
    /// away): distance, segment, parameter.
    fn nearest(&self, p: Vec3, max: f32) -> Option<(f32, Segment, f32)> {
        if self.segments.is_empty() {
            return None;
        }
        let rings = ((max / self.cell).ceil() as i32).clamp(0, 2);
        let c = self.key(p);
        let mut best: Option<(f32, Segment, f32)> = None;
        for dx in -rings..=rings {
            for dy in -rings..=rings {
                for dz in -rings..=rings {
                    // Saturating: cell keys of far-flung (hostile) coordinates sit
                    // at the ends of i32.
                    let key = [
                        c[0].saturating_add(dx),
                        c[1].saturating_add(dy),
                        c[2].saturating_add(dz),
                    ];
                    let Some(list) = self.cells.get(&key) else {
                        continue;
                    };
                    for &id in list {
                        let seg = self.segments[id as usize];
                        let (s, d) = closest_on_segment(p, seg.a, seg.b);
                        if d < max && best.is_none_or(|x| d < x.0) {
                            best = Some((d, seg, s));
                        }
                    }
                }
            }
        }
        best
    }
}

/// Attaches `leaves` to the skeleton `nodes` (canonical order, at least two
/// nodes), growing twigs to leaves with no wood under them.
pub(crate) fn attach(nodes: Vec<Node>, leaves: &[LeafGeometry]) -> Attached {
    let mut nodes = nodes;
    let points: Vec<Vec3> = nodes.iter().map(|n| n.position).collect();
    let segments: Vec<(u32, u32)> = nodes
        .iter()
        .enumerate()
        .filter_map(|(i, n)| n.parent.map(|p| (p, i as u32)))
        .collect();
    let mut lengths: Vec<f32> = segments
        .iter()
        .map(|&(a, b)| points[a as usize].distance(points[b as usize]))
        .collect();
    let total: f32 = lengths.iter().sum();
    let mid = lengths.len() / 2;
    let median = *lengths.select_nth_unstable_by(mid, f32::total_cmp).1;
    let step = (0.5 * median).max(total / 400_000.0).max(1e-6);
    let index = SegmentIndex::new(&points, &segments, step);
    let nearest = |p: Vec3| {
        let mut best: Option<(f32, u32, f32)> = None;
        for seg in index.near(p, 12) {
            let (a, b) = segments[seg as usize];
            let (s, d) = closest_on_segment(p, points[a as usize], points[b as usize]);
            if best.is_none_or(|x| d < x.0) {
                best = Some((d, seg, s));
            }
        }
        best
    };

    let mut pending: Vec<Pending> = Vec::with_capacity(leaves.len());
    // (distance to the skeleton, leaf, segment, parameter) of far leaves.
    let mut far: Vec<(f32, LeafGeometry, Segment, f32)> = Vec::new();
    for leaf in leaves {
        let mut leaf = *leaf;
        let Some(mut hit) = nearest(leaf.anchor) else {
            continue;
        };
        if leaf.base_unknown {
            let other = leaf.flipped();
            if let Some(h) = nearest(other.anchor)
                && h.0 < hit.0
            {
                leaf = other;
                hit = h;
            }
        }
        let (d, seg, s) = hit;
        let segment =
            Segment::of(&nodes, segments[seg as usize].1).expect("a segment has a parent");
        let (_, r) = segment.at(s);
        if d <= r + REACH * size(&leaf) {
            pending.push(Pending { segment, s, leaf });
        } else {
            far.push((d, leaf, segment, s));
        }
    }

    // Nearest first, so twigs grow outward from the wood and later leaves
    // can hang from or branch off the twigs grown before them.
    far.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut sizes: Vec<f32> = far.iter().map(|f| size(&f.1)).collect();
    let cell = if sizes.is_empty() {
        1.0
    } else {
        let mid = sizes.len() / 2;
        (2.0 * *sizes.select_nth_unstable_by(mid, f32::total_cmp).1).max(1e-4)
    };
    let mut grid = Grid {
        cell,
        cells: FxMap::default(),
        segments: Vec::new(),
    };
    let mut splits: FxMap<u32, Vec<(f32, u32)>> = FxMap::default();
    let mut grown_twigs = 0usize;
    // Whether a node is the tip of a grown twig.
    let mut tips: Vec<bool> = Vec::new();
    for (d0, leaf, seg0, s0) in far {
        let size = size(&leaf);
        let (_, segment, s) = match grid.nearest(leaf.anchor, d0) {
            Some(hit) => hit,
            None => (d0, seg0, s0),
        };
        let (point, r) = segment.at(s);
        let d = leaf.anchor.distance(point);
        if d <= r + REACH * size {
            pending.push(Pending { segment, s, leaf });
            continue;
        }
        let snap = (0.25 * size).max(1e-5);
        let base = split(&mut nodes, &mut splits, &segment, s, snap);
        let start = nodes[base as usize];
        let length = start.position.distance(leaf.anchor);
        if length < 1e-5 {
            pending.push(Pending { segment, s, leaf });
            continue;
        }
        // Growing on from a grown twig's tip extends that twig.
        match tips.get_mut(base as usize) {
            Some(tip) if *tip => *tip = false,
            _ => grown_twigs += 1,
        }
        let count = ((length / (TWIG_SEGMENT * size)).ceil() as usize).clamp(1, 3);
        let r0 = start.radius.min(TWIG_RADIUS * size).max(1e-6);
        let mut parent = base;
        for k in 1..=count {
            let f = k as f32 / count as f32;
            let id = nodes.len() as u32;
            nodes.push(Node {
                position: start.position.lerp(leaf.anchor, f),
                radius: r0 * (1.0 - 0.5 * f),
                parent: Some(parent),
            });
            let seg = Segment::of(&nodes, id).expect("a grown node has a parent");
            grid.insert(seg);
            parent = id;
        }
        tips.resize(nodes.len(), false);
        tips[parent as usize] = true;
        let tip = Segment::of(&nodes, parent).expect("a grown node has a parent");
        pending.push(Pending {
            segment: tip,
            s: 1.0,
            leaf,
        });
    }

    // Chain the split points of each segment in order along it.
    for (&node, list) in splits.iter_mut() {
        list.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut prev = nodes[node as usize]
            .parent
            .expect("a split segment has a parent");
        for &(_, m) in list.iter() {
            nodes[m as usize].parent = Some(prev);
            prev = m;
        }
        nodes[node as usize].parent = Some(prev);
    }
    let leaves = pending
        .into_iter()
        .map(|p| {
            let (point, _) = p.segment.at(p.s);
            let (branch, t) = match splits.get(&p.segment.node) {
                None => (p.segment.node, p.s),
                Some(list) => {
                    let i = list.partition_point(|x| x.0 < p.s);
                    let lo = if i == 0 { 0.0 } else { list[i - 1].0 };
                    let (hi, branch) = list.get(i).map_or((1.0, p.segment.node), |&(s, m)| (s, m));
                    (branch, ((p.s - lo) / (hi - lo)).clamp(0.0, 1.0))
                }
            };
            let leaf = p.leaf;
            Leaf {
                branch,
                t,
                offset: leaf.anchor - point,
                width: leaf.width,
                height: leaf.height,
                orientation: leaf.orientation,
                material: leaf.material,
            }
        })
        .collect();
    Attached {
        nodes,
        leaves,
        grown_twigs,
    }
}

/// A leaf's size: the larger of its width and height.
fn size(leaf: &LeafGeometry) -> f32 {
    leaf.width.max(leaf.height)
}

/// The node at parameter `s` of `segment` (as it was before any split):
/// an end or an earlier split within `snap` metres, else a new node.
fn split(
    nodes: &mut Vec<Node>,
    splits: &mut FxMap<u32, Vec<(f32, u32)>>,
    segment: &Segment,
    s: f32,
    snap: f32,
) -> u32 {
    let length = segment.a.distance(segment.b);
    if s * length <= snap {
        return segment.parent;
    }
    if (1.0 - s) * length <= snap {
        return segment.node;
    }
    let list = splits.entry(segment.node).or_default();
    if let Some(&(_, m)) = list.iter().find(|x| (x.0 - s).abs() * length <= snap) {
        return m;
    }
    let (position, radius) = segment.at(s);
    let id = nodes.len() as u32;
    // The parent is fixed once every split of the segment is known.
    nodes.push(Node {
        position,
        radius,
        parent: Some(segment.parent),
    });
    list.push((s, id));
    id
}
