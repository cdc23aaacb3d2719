//! The plausibility check: [`Plausibility`], its input [`MeshView`], its
//! [`PlausibilityOptions`] and its [`Report`].

use glam::{Vec3, Vec3A};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use thiserror::Error;
use treemorph_gltf::frames::FrameMeshes;
use treemorph_gltf::mesh::{LeafShape, MeshBuffers};
use treemorph_tree::{FrameTopology, NodeId};

use crate::geometry::{point_triangle_sq, triangle_triangle_sq};
use crate::sweep::{Found, LeafQuestion, Sweep, Triangles, VertexQuestion, box_gap_sq};
use treemorph_tree::grid::TriangleGrid;

/// How the leaf mesh's vertices group into leaves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum LeafLayout {
    /// Leaf `i` owns vertices `i·n .. (i + 1)·n` (what
    /// [`LeafMesher`](treemorph_gltf::LeafMesher) writes), so leaf indices
    /// in the report are the topology's.
    Uniform {
        /// Vertices per leaf (at least 1).
        vertices_per_leaf: u32,
    },
    /// Each connected component of the leaf triangles (by shared vertex
    /// indices) is a leaf; leaves are numbered in order of their smallest
    /// vertex index. For meshes read back from files: a crossed billboard
    /// whose quads share no vertex counts as two leaves.
    Components,
}

/// One frame's meshes as written: branch triangles and leaf triangles, in
/// metres, Y up.
#[derive(Clone, Copy, Debug)]
pub struct MeshView<'a> {
    /// Branch mesh vertex positions.
    pub branch_positions: &'a [Vec3],
    /// Branch triangle indices (a multiple of 3, each below
    /// `branch_positions.len()`).
    pub branch_indices: &'a [u32],
    /// Leaf mesh vertex positions.
    pub leaf_positions: &'a [Vec3],
    /// Leaf triangle indices.
    pub leaf_indices: &'a [u32],
    /// How leaf vertices group into leaves.
    pub leaves: LeafLayout,
}

impl<'a> MeshView<'a> {
    /// The meshes of the gltf crate's meshers (the buffers every frame GLB
    /// is written from).
    pub fn of_buffers(
        branches: &'a MeshBuffers,
        leaves: &'a MeshBuffers,
        shape: LeafShape,
    ) -> MeshView<'a> {
        MeshView {
            branch_positions: &branches.positions,
            branch_indices: &branches.indices,
            leaf_positions: &leaves.positions,
            leaf_indices: &leaves.indices,
            leaves: LeafLayout::Uniform {
                vertices_per_leaf: shape.vertices_per_leaf() as u32,
            },
        }
    }

    /// The last frame meshed by `meshes` — after
    /// [`FrameGlbWriter::write_into`](treemorph_gltf::frame_glb::FrameGlbWriter::write_into),
    /// `writer.meshes()` holds exactly the geometry of the GLB just written.
    pub fn of_frame_meshes(meshes: &'a FrameMeshes) -> MeshView<'a> {
        MeshView::of_buffers(
            meshes.branches().buffers(),
            meshes.leaves().buffers(),
            meshes.leaves().shape(),
        )
    }
}

/// Options of [`Plausibility`].
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct PlausibilityOptions {
    /// A leaf floats when its nearest vertex is farther from the branch
    /// surface than half its size plus this fraction of the frame's height
    /// (default 0.005: 0.5 %).
    pub leaf_slack: f32,
    /// A branch piece floats when it comes nowhere within this fraction of
    /// the frame's height of another piece (default 0.02: 2 %).
    pub branch_reach: f32,
    /// Measure each floating leaf's exact distance to the branch surface
    /// (default `true`; costs a k-d tree build on frames with floating
    /// leaves). When `false`, [`FloatingLeaf::gap`] and
    /// [`Report::worst_leaf_gap`] are `NaN`.
    pub exact_gaps: bool,
}

impl Default for PlausibilityOptions {
    fn default() -> PlausibilityOptions {
        PlausibilityOptions {
            leaf_slack: 0.005,
            branch_reach: 0.02,
            exact_gaps: true,
        }
    }
}

impl PlausibilityOptions {
    /// These options with [`PlausibilityOptions::leaf_slack`] set.
    #[must_use]
    pub fn with_leaf_slack(mut self, fraction: f32) -> PlausibilityOptions {
        self.leaf_slack = fraction;
        self
    }

    /// These options with [`PlausibilityOptions::branch_reach`] set.
    #[must_use]
    pub fn with_branch_reach(mut self, fraction: f32) -> PlausibilityOptions {
        self.branch_reach = fraction;
        self
    }

    /// These options with [`PlausibilityOptions::exact_gaps`] set.
    #[must_use]
    pub fn with_exact_gaps(mut self, exact: bool) -> PlausibilityOptions {
        self.exact_gaps = exact;
        self
    }
}

/// Why a frame could not be checked (the caller's mistake).
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum VerifyError {
    /// An index buffer's length is not a multiple of 3.
    #[error("the {mesh} index count {count} is not a multiple of 3")]
    NotTriangles {
        /// `"branch"` or `"leaf"`.
        mesh: &'static str,
        /// The index count.
        count: usize,
    },
    /// An index names a vertex that does not exist.
    #[error("{mesh} index {index} is out of range for {vertices} vertices")]
    IndexOutOfRange {
        /// `"branch"` or `"leaf"`.
        mesh: &'static str,
        /// The offending index.
        index: u32,
        /// The vertex count.
        vertices: usize,
    },
    /// A vertex position is NaN or infinite.
    #[error("{mesh} vertex {vertex} is not finite")]
    NotFinite {
        /// `"branch"` or `"leaf"`.
        mesh: &'static str,
        /// The vertex.
        vertex: usize,
    },
    /// Invalid options or layout.
    #[error("invalid options: {0}")]
    InvalidOptions(String),
}

/// A leaf that floats.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloatingLeaf {
    /// The leaf's index (see [`LeafLayout`]).
    pub leaf: u32,
    /// Distance from its nearest vertex to the branch surface, metres
    /// (`INFINITY` when the frame has no branch surface, `NaN` without
    /// [`PlausibilityOptions::exact_gaps`]).
    pub gap: f32,
    /// The distance it was allowed: half its size plus the slack, metres.
    pub allowed: f32,
    /// Its size: the largest distance between two of its vertices, metres.
    pub size: f32,
}

/// A branch piece that floats.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloatingPiece {
    /// The piece's smallest vertex index in the branch mesh.
    pub first_vertex: u32,
    /// Its visible triangles.
    pub triangles: u32,
    /// Its lowest vertex.
    pub lowest: Vec3,
}

/// What [`Plausibility::check`] measured on one frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Report {
    /// The frame's height: the extent along Y of all its vertices, metres.
    pub height: f32,
    /// Leaves checked: those of non-zero size (zero-size leaves are not
    /// drawn and are skipped).
    pub leaves: u32,
    /// Leaves that float.
    pub floating_leaves: u32,
    /// The largest [`FloatingLeaf::gap`], metres; 0 when none floats.
    pub worst_leaf_gap: f32,
    /// Visible branch pieces (connected components with a triangle of
    /// non-zero area).
    pub branch_pieces: u32,
    /// Pieces other than the root that float.
    pub floating_branches: u32,
    /// The floating leaves, by leaf index.
    pub floating: Vec<FloatingLeaf>,
    /// The floating pieces, by first vertex.
    pub floating_pieces: Vec<FloatingPiece>,
}

/// The output-level plausibility check: a reusable context whose buffers
/// (connected components, the triangle table) persist between frames, and
/// whose component labelling is reused while a sequence's index buffers
/// stay the same.
///
/// ```
/// use glam::Vec3;
/// use treemorph_verify::{LeafLayout, MeshView, Plausibility, PlausibilityOptions};
/// // A unit square of "bark" at y = 0 and a leaf touching it.
/// let bark = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, 1.0), Vec3::Z, Vec3::Y * 10.0];
/// let leaf = [Vec3::new(0.5, 0.0, 0.5), Vec3::new(0.6, 0.1, 0.5), Vec3::new(0.5, 0.1, 0.6)];
/// let view = MeshView {
///     branch_positions: &bark,
///     branch_indices: &[0, 1, 2, 0, 2, 3],
///     leaf_positions: &leaf,
///     leaf_indices: &[0, 1, 2],
///     leaves: LeafLayout::Components,
/// };
/// let report = Plausibility::new().check(&view, &PlausibilityOptions::default())?;
/// assert_eq!((report.leaves, report.floating_leaves), (1, 0));
/// # Ok::<(), treemorph_verify::VerifyError>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct Plausibility {
    /// The branch index buffer the labels below belong to.
    branch_key: Vec<u32>,
    branch_vertices: usize,
    /// Per branch vertex, its piece (dense 0..pieces).
    piece_of: Vec<u32>,
    /// Per piece, its smallest vertex.
    piece_first: Vec<u32>,
    pieces: usize,
    /// The leaf index buffer and layout the leaf grouping belongs to.
    leaf_key: Vec<u32>,
    leaf_key_layout: Option<(LeafLayout, usize)>,
    /// Leaf `i`'s vertices are `leaf_vertices[leaf_starts[i]..leaf_starts[i + 1]]`.
    leaf_starts: Vec<u32>,
    leaf_vertices: Vec<u32>,
    /// Union–find scratch.
    parent: Vec<u32>,
    /// The frame's visible branch triangles, their piece and bounds.
    tris: Vec<[Vec3; 3]>,
    tri_piece: Vec<u32>,
    boxes: Vec<(Vec3, Vec3)>,
    grid: TriangleGrid,
    /// The grid's cell side this frame, and whether it is built yet: it is
    /// built only when a proof from the last frame and the local search
    /// leave a leaf or a piece open, which on most frames of a sequence
    /// none does.
    cell: f32,
    grid_built: bool,
    /// What settles the leaves and pieces the proofs leave open.
    sweep: Sweep,
    /// The frame's bounds.
    frame_bounds: (Vec3, Vec3),
    /// Per piece, the bounds of its visible triangles, once gathered this
    /// frame (`pieces_bounded`).
    piece_boxes: Vec<(Vec3, Vec3)>,
    pieces_bounded: bool,
    /// The root piece: the one holding the lowest vertex of a visible
    /// triangle (the first such vertex, in triangle order).
    root: Option<u32>,
    /// Leaves and pieces left open by the shortcuts this frame, and the
    /// open leaves' vertices.
    open_leaves: Vec<OpenLeaf>,
    open_pieces: Vec<u32>,
    open_points: Vec<Vec3>,
    /// Visible triangles by piece: `piece_tris[piece_starts[p]..piece_starts[p + 1]]`.
    piece_starts: Vec<u32>,
    piece_tris: Vec<u32>,
    /// Scratch: one leaf's vertex positions.
    scratch: Vec<Vec3>,
    /// Per piece, its vertices: `piece_verts[piece_vert_starts[p]..piece_vert_starts[p + 1]]`
    /// (ascending, so a tube's base ring comes first).
    piece_vert_starts: Vec<u32>,
    piece_verts: Vec<u32>,
    /// Per branch triangle of the index buffer, its index among this
    /// frame's visible triangles (`u32::MAX` when invisible).
    visible_of: Vec<u32>,
    /// Per branch vertex, whether a visible triangle uses it.
    vertex_visible: Vec<bool>,
    /// Per visible triangle, its index in the index buffer.
    tri_orig: Vec<u32>,
    /// Per piece, what proved it near another piece last frame: tried
    /// first on the next.
    partner: Vec<Partner>,
    /// Per leaf, what proved it attached last frame — one of its vertices
    /// (by rank among the leaf's) and a triangle (by index in the index
    /// buffer) — tried first on the next.
    leaf_proof: Vec<(u32, u32)>,
    /// Where the shortcuts look when no proof is kept ([`Hints`]).
    hints: Hints,
    /// The proofs (`leaf_proof`, `partner`) of the first frame of the last
    /// sequence, and whether the next check starts a sequence
    /// ([`Plausibility::start_sequence`]).
    first_proofs: Option<Proofs>,
    starting: bool,
    /// Per piece, the piece its hint names as the one it grows from
    /// (`u32::MAX`: none), for the labels above (`None`: not yet made).
    host_pieces: Option<Vec<u32>>,
}

/// Where the check looks first for what attaches a leaf or a piece, when
/// it keeps no proof from a frame before (a sequence's first frame): the
/// tube each grows from, as the writer of the meshes knows it. A hint
/// only orders the search: a wrong or missing one costs time, never a
/// verdict, since whatever it names is measured like anything else.
/// Without hints, every leaf and piece of a first frame is searched for
/// in a grid of all the frame's triangles (30-34 ms of the default job's
/// first check); with them, that frame leaves none open.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Hints {
    /// Per leaf (a [`LeafLayout::Uniform`] leaf index), a branch vertex of
    /// the tube it grows from (`u32::MAX`: none).
    pub leaf_hosts: Vec<u32>,
    /// Pairs of branch vertices: one of a tube, one of the tube it grows
    /// from.
    pub tube_hosts: Vec<(u32, u32)>,
}

impl Hints {
    /// The hints of meshes written from `topology` whose branch vertices
    /// belong to the strands `owners` names (per vertex, its strand and
    /// node, as [`BranchMesher::vertex_owners`] lists them): each leaf's
    /// host is the tube of the strand that owns its node, each tube's the
    /// tube of its parent strand.
    ///
    /// [`BranchMesher::vertex_owners`]: treemorph_gltf::mesh::BranchMesher::vertex_owners
    pub fn of_tubes(topology: &FrameTopology, owners: &[(u32, NodeId)]) -> Hints {
        let mut first = vec![u32::MAX; topology.strands.len()];
        for (v, &(strand, _)) in owners.iter().enumerate().rev() {
            if let Some(f) = first.get_mut(strand as usize) {
                *f = v as u32;
            }
        }
        let vertex_of = |strand: Option<u32>| {
            strand
                .and_then(|s| first.get(s as usize).copied())
                .unwrap_or(u32::MAX)
        };
        let node_owners = topology.node_owners();
        let leaf_hosts = topology
            .leaves
            .iter()
            .map(|l| vertex_of(node_owners.get(l.node as usize).copied().flatten()))
            .collect();
        let tube_hosts = topology
            .strand_parents()
            .iter()
            .enumerate()
            .map(|(s, &parent)| (vertex_of(Some(s as u32)), vertex_of(parent)))
            .filter(|&(a, b)| a != u32::MAX && b != u32::MAX)
            .collect();
        Hints {
            leaf_hosts,
            tube_hosts,
        }
    }
}

/// The frame's visible triangles and one leaf's vertices, for the leaf
/// searches.
#[derive(Clone, Copy)]
struct Near<'a> {
    tris: &'a [[Vec3; 3]],
    boxes: &'a [(Vec3, Vec3)],
    pts: &'a [Vec3],
}

impl<'a> Near<'a> {
    fn of(tris: &'a [[Vec3; 3]], boxes: &'a [(Vec3, Vec3)], pts: &'a [Vec3]) -> Near<'a> {
        Near { tris, boxes, pts }
    }

    /// The rank of the leaf's first vertex within `allowed2` of visible
    /// triangle `t`, if any (`lo`, `hi`: the leaf's bounds).
    fn leaf(self, (lo, hi): (Vec3, Vec3), allowed2: f32, reference: bool, t: u32) -> Option<u32> {
        let b = self.boxes[t as usize];
        if box_gap_sq((lo, hi), b) > allowed2 {
            return None;
        }
        let tri = self.tris[t as usize];
        // A vertex's gap to the triangle's bounds is cheap and rules most
        // vertices out before the exact distance.
        let k = self.pts.iter().position(|&p| {
            (reference || box_gap_sq((p, p), b) <= allowed2)
                && point_triangle_sq(p, tri) <= allowed2
        })?;
        Some(k as u32)
    }
}

/// Leaf `leaf`'s vertices, by the grouping `starts` and `vertices` (see
/// [`Plausibility`]'s `leaf_starts`).
fn leaf_vertex_ids<'a>(starts: &[u32], vertices: &'a [u32], leaf: usize) -> &'a [u32] {
    &vertices[starts[leaf] as usize..starts[leaf + 1] as usize]
}

/// The positions of vertices `ids` into `points`, and their bounds.
fn gather_leaf(positions: &[Vec3], ids: &[u32], points: &mut Vec<Vec3>) -> (Vec3, Vec3) {
    points.clear();
    points.extend(ids.iter().map(|&v| positions[v as usize]));
    points
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        })
}

/// Open leaves at least this many are searched on two threads
/// ([`Plausibility::search_leaves`]); fewer cost less than the split.
const PARALLEL_LEAVES: usize = 2_048;

/// What the leaf search reads: the frame's visible triangles by piece,
/// the leaves' vertices and the triangle grid, shared by the threads.
struct LeafSearch<'a> {
    tris: &'a [[Vec3; 3]],
    boxes: &'a [(Vec3, Vec3)],
    tri_piece: &'a [u32],
    piece_starts: &'a [u32],
    piece_tris: &'a [u32],
    leaf_starts: &'a [u32],
    leaf_vertices: &'a [u32],
    positions: &'a [Vec3],
    grid: &'a TriangleGrid,
    reference: bool,
}

impl LeafSearch<'_> {
    /// A vertex (by rank) and a triangle within reach for each of `open`,
    /// in order.
    fn run(&self, open: &[OpenLeaf]) -> Vec<Option<(u32, u32)>> {
        let mut hits = Vec::with_capacity(open.len());
        let mut points = Vec::new();
        // The piece the last leaf was found on: leaves are numbered along
        // their twigs, so most are found on their predecessor's twig.
        let mut last = None;
        for o in open {
            let vs = leaf_vertex_ids(self.leaf_starts, self.leaf_vertices, o.leaf as usize);
            let (lo, hi) = gather_leaf(self.positions, vs, &mut points);
            let near = Near::of(self.tris, self.boxes, &points);
            let allowed2 = o.allowed * o.allowed;
            let on_last = last.filter(|_| !self.reference).and_then(|piece: u32| {
                let list = self.piece_starts[piece as usize] as usize
                    ..self.piece_starts[piece as usize + 1] as usize;
                self.piece_tris[list]
                    .iter()
                    .find_map(|&t| near.leaf((lo, hi), allowed2, false, t).map(|k| (k, t)))
            });
            let mut hit = on_last;
            if hit.is_none() {
                self.grid
                    .any_near_shared(lo - o.allowed, hi + o.allowed, |t| {
                        hit = near
                            .leaf((lo, hi), allowed2, self.reference, t)
                            .map(|k| (k, t));
                        hit.is_some()
                    });
            }
            last = hit.map(|(_, t)| self.tri_piece[t as usize]).or(last);
            hits.push(hit);
        }
        hits
    }
}

/// A leaf the shortcuts could not settle: its index, size and allowed
/// distance, for the exhaustive search.
#[derive(Clone, Copy, Debug)]
struct OpenLeaf {
    leaf: u32,
    size: f32,
    allowed: f32,
}

/// What proved each leaf and piece attached in one frame (`leaf_proof`,
/// `partner`).
#[derive(Clone, Debug)]
struct Proofs {
    leaves: Vec<(u32, u32)>,
    pieces: Vec<Partner>,
}

/// A proof that a piece comes within reach of another, kept between
/// frames (indices into the branch mesh, stable while it is unchanged).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Partner {
    #[default]
    None,
    /// A vertex of the piece within reach of a triangle (by its index in
    /// the index buffer) of another piece.
    Vertex(u32, u32),
    /// Two triangles (index-buffer indices), the piece's and another's,
    /// within reach.
    Triangles(u32, u32),
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        // The smaller root wins, so roots are each component's smallest vertex.
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        parent[hi as usize] = lo;
    }
}

/// Checks an index buffer against its vertices (`known`: the same buffer
/// and vertex count passed last frame, so only their number of indices is
/// looked at).
fn check_indices(
    mesh: &'static str,
    vertices: usize,
    indices: &[u32],
    known: bool,
) -> Result<(), VerifyError> {
    if !indices.len().is_multiple_of(3) {
        return Err(VerifyError::NotTriangles {
            mesh,
            count: indices.len(),
        });
    }
    if known {
        return Ok(());
    }
    if let Some(&index) = indices.iter().find(|&&i| i as usize >= vertices) {
        return Err(VerifyError::IndexOutOfRange {
            mesh,
            index,
            vertices,
        });
    }
    Ok(())
}

/// The bounds of `positions` (folded into `bounds`), refusing a position
/// that is not finite. One pass: the sum of all coordinates is finite
/// when every coordinate is (a sum that overflows only sends it to the
/// exact scan).
fn checked_bounds(
    mesh: &'static str,
    positions: &[Vec3],
    bounds: (Vec3, Vec3),
) -> Result<(Vec3, Vec3), VerifyError> {
    let (mut lo, mut hi, mut sum) = (bounds.0, bounds.1, Vec3::ZERO);
    for &p in positions {
        lo = lo.min(p);
        hi = hi.max(p);
        sum += p;
    }
    if !sum.is_finite()
        && let Some(vertex) = positions.iter().position(|p| !p.is_finite())
    {
        return Err(VerifyError::NotFinite { mesh, vertex });
    }
    Ok((lo, hi))
}

/// Vertices of an open piece (its first, which for a tube are its base
/// ring) the sweep asks about; a piece none of them settles goes to the
/// exhaustive search.
const BASE_VERTICES: usize = 8;

/// More open questions than this in a frame go to the triangle grid
/// instead of a sweep.
const MANY_OPEN: usize = 4_000;

impl Plausibility {
    /// A context with empty buffers.
    pub fn new() -> Plausibility {
        Plausibility::default()
    }

    /// Sets where the shortcuts look first ([`Hints`]).
    pub fn set_hints(&mut self, hints: Hints) {
        self.hints = hints;
        self.host_pieces = None;
    }

    /// Starts a new sequence of frames with `hints`: forgets what proved
    /// each leaf and piece attached in the last frame checked, as a new
    /// context has no such proofs, and keeps the buffers and the labels of
    /// the last index buffers (each frame's are compared with them before
    /// they are used). A context kept from job to job skips, on its next
    /// job's first frame, the first touches of its buffers' pages and, for
    /// the same meshes, the labelling of pieces (in a profile of the
    /// default job's first check, its triangle pass and the labelling
    /// took about 40 %). Reports are those of a new context.
    ///
    /// A sequence's first frame is often the last one's (a job run again:
    /// frame 0 is the plan at t = 0). So the proofs found on the last
    /// sequence's first frame are tried first on the next one's when its
    /// meshes have the same index buffers, where they name the same
    /// vertices and triangles; like any proof they are measured again.
    pub fn start_sequence(&mut self, hints: Hints) {
        self.leaf_proof.clear();
        self.partner.fill(Partner::None);
        self.set_hints(hints);
        self.starting = true;
    }

    /// At a sequence's first frame, takes up the proofs of the last
    /// sequence's first frame when the index buffers are those they were
    /// found on (`same_meshes`).
    fn resume_first_proofs(&mut self, same_meshes: bool) {
        if let (true, Some(first)) = (same_meshes, &self.first_proofs) {
            self.leaf_proof.clone_from(&first.leaves);
            self.partner.clone_from(&first.pieces);
        }
    }

    /// Checks one frame with a fresh context.
    pub fn of(meshes: &MeshView<'_>, options: &PlausibilityOptions) -> Result<Report, VerifyError> {
        Plausibility::new().check(meshes, options)
    }

    /// Checks one frame (see the [crate docs](crate) for what is measured).
    pub fn check(
        &mut self,
        meshes: &MeshView<'_>,
        options: &PlausibilityOptions,
    ) -> Result<Report, VerifyError> {
        self.run(meshes, options, false)
    }

    /// [`Plausibility::check`] without its shortcuts: every piece by the
    /// exact triangle–triangle search alone, no proof kept from the last
    /// frame. The reference the fast check is tested against; same
    /// [`Report`].
    #[doc(hidden)]
    pub fn check_reference(
        &mut self,
        meshes: &MeshView<'_>,
        options: &PlausibilityOptions,
    ) -> Result<Report, VerifyError> {
        self.run(meshes, options, true)
    }

    fn run(
        &mut self,
        meshes: &MeshView<'_>,
        options: &PlausibilityOptions,
        reference: bool,
    ) -> Result<Report, VerifyError> {
        let valid = |x: f32| x.is_finite() && x >= 0.0;
        if !valid(options.leaf_slack) || !valid(options.branch_reach) {
            return Err(VerifyError::InvalidOptions(format!(
                "leaf_slack and branch_reach must be non-negative fractions; got {} and {}",
                options.leaf_slack, options.branch_reach
            )));
        }
        let (branches, leaves) = (meshes.branch_positions.len(), meshes.leaf_positions.len());
        let known_branches =
            self.branch_vertices == branches && self.branch_key == meshes.branch_indices;
        let same_leaf_indices = self.leaf_key == meshes.leaf_indices;
        let known_leaves =
            same_leaf_indices && self.leaf_key_layout.is_some_and(|(_, n)| n == leaves);
        check_indices("branch", branches, meshes.branch_indices, known_branches)?;
        check_indices("leaf", leaves, meshes.leaf_indices, known_leaves)?;
        let empty = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let bounds = checked_bounds("branch", meshes.branch_positions, empty)?;
        let (lo, hi) = checked_bounds("leaf", meshes.leaf_positions, bounds)?;
        self.frame_bounds = (lo, hi);
        let height = if lo.y <= hi.y { hi.y - lo.y } else { 0.0 };
        let diagonal = if lo.x <= hi.x {
            (hi - lo).length()
        } else {
            0.0
        };

        let starting = std::mem::take(&mut self.starting) && !reference;
        if starting {
            self.resume_first_proofs(known_branches && known_leaves);
        }
        self.label_pieces(meshes, known_branches);
        self.group_leaves(meshes, same_leaf_indices)?;
        self.collect_triangles(meshes);
        // Cells of about the branch reach (and twice a typical leaf's
        // allowance): a query spans a cell or two each way, and a thin
        // tube's triangle sits in one or two cells, which keeps the build
        // (the bulk of a clean frame's cost) short; bounded below so a
        // flat or tiny frame stays sane.
        self.cell = (0.02 * height).max(diagonal / 1024.0).max(1e-6);
        self.grid_built = false;

        let mut report = Report {
            height,
            ..Report::default()
        };
        let reach = options.branch_reach * height;
        self.open_leaves(meshes, options.leaf_slack * height, reference, &mut report);
        self.open_pieces(meshes, reach, reference, &mut report);
        // A sweep reads every triangle once: worth it for the few hundred
        // questions a frame of a sequence leaves open, not for a first
        // frame, where every leaf and piece is open and the triangle grid
        // answers each in a few cells.
        let many = self.open_leaves.len() + BASE_VERTICES * self.open_pieces.len() > MANY_OPEN;
        let found = if reference || many {
            Found {
                leaves: self.search_leaves(meshes, reference),
                pieces: vec![None; self.open_pieces.len()],
            }
        } else {
            self.sweep_open(meshes, reach)
        };
        self.settle_leaves(meshes, options, found.leaves, reference, &mut report);
        self.settle_pieces(meshes, found.pieces, reach, reference, &mut report);
        if starting {
            self.first_proofs = Some(Proofs {
                leaves: self.leaf_proof.clone(),
                pieces: self.partner.clone(),
            });
        }
        Ok(report)
    }

    /// Labels branch vertices by connected component, unless the index
    /// buffer is the one labelled last time.
    fn label_pieces(&mut self, meshes: &MeshView<'_>, known: bool) {
        if known {
            return;
        }
        let n = meshes.branch_positions.len();
        self.branch_key.clear();
        self.branch_key.extend_from_slice(meshes.branch_indices);
        self.branch_vertices = n;
        self.parent.clear();
        self.parent.extend(0..n as u32);
        for t in meshes.branch_indices.chunks_exact(3) {
            union(&mut self.parent, t[0], t[1]);
            union(&mut self.parent, t[0], t[2]);
        }
        self.piece_of.clear();
        self.piece_of.resize(n, u32::MAX);
        let mut pieces = 0u32;
        self.piece_first.clear();
        for v in 0..n as u32 {
            let root = find(&mut self.parent, v);
            if root == v {
                self.piece_first.push(v);
                self.piece_of[v as usize] = pieces;
                pieces += 1;
            } else {
                self.piece_of[v as usize] = self.piece_of[root as usize];
            }
        }
        self.pieces = pieces as usize;
        self.piece_vert_starts.clear();
        self.piece_vert_starts.resize(self.pieces + 1, 0);
        for &piece in &self.piece_of {
            self.piece_vert_starts[piece as usize + 1] += 1;
        }
        for i in 0..self.pieces {
            self.piece_vert_starts[i + 1] += self.piece_vert_starts[i];
        }
        self.piece_verts.clear();
        self.piece_verts.resize(n, 0);
        self.parent.clear();
        self.parent
            .extend_from_slice(&self.piece_vert_starts[..self.pieces]);
        for (v, &piece) in self.piece_of.iter().enumerate() {
            let at = &mut self.parent[piece as usize];
            self.piece_verts[*at as usize] = v as u32;
            *at += 1;
        }
        self.partner.clear();
        self.partner.resize(self.pieces, Partner::None);
        self.host_pieces = None;
    }

    /// The piece `vertex` belongs to, if it is a branch vertex.
    fn piece_of_vertex(&self, vertex: u32) -> Option<u32> {
        self.piece_of.get(vertex as usize).copied()
    }

    /// Per piece, the piece its tube hint names as its host.
    fn host_pieces(&mut self) -> &[u32] {
        if self.host_pieces.is_none() {
            let mut hosts = vec![u32::MAX; self.pieces];
            for &(tube, host) in &self.hints.tube_hosts {
                if let (Some(p), Some(h)) = (self.piece_of_vertex(tube), self.piece_of_vertex(host))
                {
                    hosts[p as usize] = h;
                }
            }
            self.host_pieces = Some(hosts);
        }
        self.host_pieces.as_deref().unwrap_or_default()
    }

    /// Groups leaf vertices into leaves, unless nothing changed.
    fn group_leaves(
        &mut self,
        meshes: &MeshView<'_>,
        same_indices: bool,
    ) -> Result<(), VerifyError> {
        let n = meshes.leaf_positions.len();
        let key = (meshes.leaves, n);
        if self.leaf_key_layout == Some(key)
            && (same_indices || matches!(meshes.leaves, LeafLayout::Uniform { .. }))
        {
            return Ok(());
        }
        self.leaf_key_layout = Some(key);
        self.leaf_proof.clear();
        self.leaf_key.clear();
        self.leaf_key.extend_from_slice(meshes.leaf_indices);
        self.leaf_starts.clear();
        self.leaf_vertices.clear();
        self.leaf_starts.push(0);
        match meshes.leaves {
            LeafLayout::Uniform { vertices_per_leaf } => {
                let k = vertices_per_leaf as usize;
                if k == 0 || !n.is_multiple_of(k) {
                    self.leaf_key_layout = None;
                    return Err(VerifyError::InvalidOptions(format!(
                        "{n} leaf vertices do not split into leaves of {k}"
                    )));
                }
                self.leaf_vertices.extend(0..n as u32);
                self.leaf_starts.extend((1..=n / k).map(|i| (i * k) as u32));
            }
            LeafLayout::Components => {
                self.parent.clear();
                self.parent.extend(0..n as u32);
                let mut used = vec![false; n];
                for t in meshes.leaf_indices.chunks_exact(3) {
                    union(&mut self.parent, t[0], t[1]);
                    union(&mut self.parent, t[0], t[2]);
                    for &v in t {
                        used[v as usize] = true;
                    }
                }
                // Counting sort of used vertices by root (roots are the
                // smallest vertex of their component).
                let mut leaf_of = vec![u32::MAX; n];
                let mut counts: Vec<u32> = Vec::new();
                for v in 0..n as u32 {
                    if !used[v as usize] {
                        continue;
                    }
                    let root = find(&mut self.parent, v) as usize;
                    if leaf_of[root] == u32::MAX {
                        leaf_of[root] = counts.len() as u32;
                        counts.push(0);
                    }
                    leaf_of[v as usize] = leaf_of[root];
                    counts[leaf_of[root] as usize] += 1;
                }
                let mut total = 0u32;
                for c in &counts {
                    total += c;
                    self.leaf_starts.push(total);
                }
                self.leaf_vertices.resize(total as usize, 0);
                let mut fill: Vec<u32> = self.leaf_starts[..counts.len()].to_vec();
                for v in 0..n as u32 {
                    let l = leaf_of[v as usize];
                    if l != u32::MAX {
                        self.leaf_vertices[fill[l as usize] as usize] = v;
                        fill[l as usize] += 1;
                    }
                }
            }
        }
        Ok(())
    }

    /// Gathers the visible branch triangles (non-zero area), their pieces
    /// and bounds, lists them by piece and finds the root piece: one pass,
    /// in which each piece's triangles are counted and the lowest vertex
    /// kept (a second pass over the triangles for each was 3 % of a job's
    /// work). The pieces' bounds, which only a sweep reads, are gathered
    /// when one runs ([`Plausibility::bound_pieces`]).
    fn collect_triangles(&mut self, meshes: &MeshView<'_>) {
        self.tris.clear();
        self.tri_piece.clear();
        self.boxes.clear();
        self.tri_orig.clear();
        self.visible_of.clear();
        self.vertex_visible.clear();
        self.vertex_visible
            .resize(meshes.branch_positions.len(), false);
        self.piece_starts.clear();
        self.piece_starts.resize(self.pieces + 1, 0);
        self.reserve_triangles(meshes.branch_indices.len() / 3);
        let p = meshes.branch_positions;
        let (mut ascending, mut last_piece) = (true, None);
        let mut lowest = (f32::INFINITY, None);
        for (i, t) in meshes.branch_indices.chunks_exact(3).enumerate() {
            // In 4-lane registers: the same products, sums and comparisons
            // (so the same visibility and bounds) in fewer instructions
            // than glam's scalar `Vec3` on the baseline target. Each is
            // made from its vertex, not from an array of the three: read
            // back from the stack, 16 bytes over three 4-byte stores, the
            // loads stalled (a third of this pass in a profile).
            let [a, b, c] = [0, 1, 2].map(|k| Vec3A::from(p[t[k] as usize]));
            if (b - a).cross(c - a).length_squared() <= 0.0 {
                self.visible_of.push(u32::MAX);
                continue;
            }
            self.visible_of.push(self.tris.len() as u32);
            self.tri_orig.push(i as u32);
            for &v in t {
                self.vertex_visible[v as usize] = true;
            }
            let piece = self.piece_of[t[0] as usize];
            self.piece_starts[piece as usize + 1] += 1;
            if last_piece != Some(piece) {
                ascending &= last_piece.is_none_or(|l| l < piece);
                last_piece = Some(piece);
            }
            // The first of the lowest vertices, in triangle order.
            for y in [a.y, b.y, c.y] {
                if y < lowest.0 {
                    lowest = (y, Some(piece));
                }
            }
            self.tris.push([a, b, c].map(Vec3::from));
            self.tri_piece.push(piece);
            self.boxes
                .push((a.min(b).min(c).into(), a.max(b).max(c).into()));
        }
        self.root = lowest.1;
        for i in 0..self.pieces {
            self.piece_starts[i + 1] += self.piece_starts[i];
        }
        self.list_by_piece(ascending);
        self.pieces_bounded = false;
    }

    /// Room for `n` triangles in the per-triangle lists, made at once: a
    /// checker's first frame grew them by doubling, each step a copy
    /// (about a sixth of that frame's triangle pass in a profile).
    fn reserve_triangles(&mut self, n: usize) {
        self.visible_of.reserve(n);
        self.tri_orig.reserve(n);
        self.tris.reserve(n);
        self.tri_piece.reserve(n);
        self.boxes.reserve(n);
    }

    /// Gathers each piece's bounds (`piece_boxes`) from its triangles',
    /// unless they are gathered this frame.
    fn bound_pieces(&mut self) {
        if self.pieces_bounded {
            return;
        }
        self.pieces_bounded = true;
        self.piece_boxes.clear();
        self.piece_boxes
            .resize(self.pieces, (Vec3::INFINITY, Vec3::NEG_INFINITY));
        // The bounds of the current run of one piece's triangles, kept in
        // registers and merged into the piece's when the run ends: merging
        // each triangle in place went through memory and was most of this
        // pass.
        let mut run: Option<(u32, Vec3A, Vec3A)> = None;
        let piece_boxes = &mut self.piece_boxes;
        let mut merge = |(piece, lo, hi): (u32, Vec3A, Vec3A)| {
            let b = &mut piece_boxes[piece as usize];
            *b = (lo.min(b.0.into()).into(), hi.max(b.1.into()).into());
        };
        for (&piece, &(lo, hi)) in self.tri_piece.iter().zip(&self.boxes) {
            match &mut run {
                Some((current, l, h)) if *current == piece => {
                    *l = l.min(lo.into());
                    *h = h.max(hi.into());
                }
                _ => {
                    if let Some(ended) = run {
                        merge(ended);
                    }
                    run = Some((piece, lo.into(), hi.into()));
                }
            }
        }
        if let Some(ended) = run {
            merge(ended);
        }
    }

    /// Lists the visible triangles by piece (`piece_tris`, with
    /// `piece_starts` counted). When the pieces come in ascending order
    /// in the index buffer, as every tube mesher writes them, the list is
    /// the triangles in order.
    fn list_by_piece(&mut self, ascending: bool) {
        self.piece_tris.clear();
        if ascending {
            self.piece_tris.extend(0..self.tris.len() as u32);
            return;
        }
        self.piece_tris.resize(self.tris.len(), 0);
        // Reuse `parent` as fill cursors (it is scratch).
        self.parent.clear();
        self.parent
            .extend_from_slice(&self.piece_starts[..self.pieces]);
        for (i, &piece) in self.tri_piece.iter().enumerate() {
            let at = &mut self.parent[piece as usize];
            self.piece_tris[*at as usize] = i as u32;
            *at += 1;
        }
    }

    /// Builds this frame's grid unless it is built.
    fn ensure_grid(&mut self) {
        if !self.grid_built {
            self.grid.build(&self.boxes, self.cell);
            self.grid_built = true;
        }
    }

    /// Leaf `leaf`'s vertices into `scratch`; its size (0 for a leaf not
    /// drawn) and bounds.
    fn leaf_points(&mut self, meshes: &MeshView<'_>, leaf: usize) -> (Vec3, Vec3) {
        let vs = leaf_vertex_ids(&self.leaf_starts, &self.leaf_vertices, leaf);
        gather_leaf(meshes.leaf_positions, vs, &mut self.scratch)
    }

    /// The size of the leaf in `scratch`: the largest distance between two
    /// of its vertices.
    fn leaf_size(&self) -> f32 {
        let pts = &self.scratch;
        let mut size2 = 0.0f32;
        for (i, a) in pts.iter().enumerate() {
            for b in &pts[i + 1..] {
                size2 = size2.max(a.distance_squared(*b));
            }
        }
        size2.sqrt()
    }

    /// Whether last frame's proof of `leaf` (in `scratch`) still holds
    /// within `allowed2`: its vertex within reach of its triangle, still
    /// visible.
    fn proof_holds(&self, leaf: usize, allowed2: f32) -> bool {
        let Some(&(k, t)) = self.leaf_proof.get(leaf) else {
            return false;
        };
        matches!(self.visible_of.get(t as usize), Some(&s) if s != u32::MAX)
            && (k as usize) < self.scratch.len()
            && point_triangle_sq(
                self.scratch[k as usize],
                self.tris[self.visible_of[t as usize] as usize],
            ) <= allowed2
    }

    /// Whether last frame's proof of `leaf` holds within a lower bound of
    /// its allowed distance, read from three of its vertices in place: the
    /// distance between its first and its middle vertex is at most its
    /// size, so half of it plus the slack is at most the allowed distance.
    /// A leaf whose two vertices are apart is drawn. Most leaves of a
    /// sequence's frame pass here, without their vertices gathered and
    /// bounded ([`Plausibility::leaf_points`]), which took most of a
    /// frame's leaf pass; the others take the exact path.
    fn proof_holds_quickly(&self, meshes: &MeshView<'_>, leaf: usize, slack: f32) -> bool {
        let Some(&(k, t)) = self.leaf_proof.get(leaf) else {
            return false;
        };
        let Some(&s) = self.visible_of.get(t as usize) else {
            return false;
        };
        let vs = leaf_vertex_ids(&self.leaf_starts, &self.leaf_vertices, leaf);
        let (Some(&proof), Some(&first)) = (vs.get(k as usize), vs.first()) else {
            return false;
        };
        let at = |v: u32| meshes.leaf_positions[v as usize];
        let apart = at(first).distance(at(vs[vs.len() / 2]));
        let least = 0.5 * apart + slack;
        s != u32::MAX
            && apart > 0.0
            && point_triangle_sq(at(proof), self.tris[s as usize]) <= least * least
    }

    /// Whether the leaf in `scratch` is attached by a shortcut: last
    /// frame's proof (a vertex within reach of a triangle still visible),
    /// or any triangle of the piece that proof's triangle belongs to (a
    /// leaf stays on its twig while it moves along it). Keeps a new proof.
    fn leaf_settled(&mut self, leaf: usize, bounds: (Vec3, Vec3), allowed2: f32) -> bool {
        if self.proof_holds(leaf, allowed2) {
            return true;
        }
        // Its own twig, else its neighbours' (leaves are numbered along
        // their twigs, so a leaf just unfolded, with no proof yet, mostly
        // sits on the twig of the leaf before or after it).
        let hint = |l: usize| {
            let &(_, t) = self.leaf_proof.get(l)?;
            let &v = self.branch_key.get(3 * t as usize)?;
            Some(self.piece_of[v as usize])
        };
        let host = self.hints.leaf_hosts.get(leaf);
        let mut pieces = [
            hint(leaf),
            leaf.checked_sub(1).and_then(hint),
            hint(leaf + 1),
            host.and_then(|&v| self.piece_of_vertex(v)),
        ];
        for i in 1..pieces.len() {
            if pieces[..i].contains(&pieces[i]) {
                pieces[i] = None;
            }
        }
        for piece in pieces.into_iter().flatten() {
            let list = self.piece_starts[piece as usize] as usize
                ..self.piece_starts[piece as usize + 1] as usize;
            let hit = self.piece_tris[list].iter().find_map(|&t| {
                let near = Near::of(&self.tris, &self.boxes, &self.scratch);
                near.leaf(bounds, allowed2, false, t).map(|k| (k, t))
            });
            if let Some((k, t)) = hit {
                self.leaf_proof[leaf] = (k, self.tri_orig[t as usize]);
                return true;
            }
        }
        false
    }

    /// Leaves not settled by a shortcut, into `open_leaves` (every leaf in
    /// the reference); counts the leaves drawn.
    fn open_leaves(
        &mut self,
        meshes: &MeshView<'_>,
        slack: f32,
        reference: bool,
        report: &mut Report,
    ) {
        let leaf_count = self.leaf_starts.len() - 1;
        if !reference && self.leaf_proof.len() != leaf_count {
            self.leaf_proof.clear();
            self.leaf_proof.resize(leaf_count, (u32::MAX, u32::MAX));
        }
        let mut open = std::mem::take(&mut self.open_leaves);
        open.clear();
        for leaf in 0..leaf_count {
            if !reference && self.proof_holds_quickly(meshes, leaf, slack) {
                report.leaves += 1;
                continue;
            }
            let (lo, hi) = self.leaf_points(meshes, leaf);
            // Its vertices all coincide (size 0) exactly when its bounds
            // are a point: a leaf not drawn.
            let side = (hi - lo).max_element();
            if side <= 0.0 {
                continue;
            }
            report.leaves += 1;
            // Half the longest side plus the slack is at most its allowed
            // distance: a proof within it needs no exact size.
            let least = 0.5 * side + slack;
            if !reference && self.proof_holds(leaf, least * least) {
                continue;
            }
            let size = self.leaf_size();
            let allowed = 0.5 * size + slack;
            if reference || !self.leaf_settled(leaf, (lo, hi), allowed * allowed) {
                open.push(OpenLeaf {
                    leaf: leaf as u32,
                    size,
                    allowed,
                });
            }
        }
        self.open_leaves = open;
    }

    /// For each open leaf, a vertex (by rank) and a visible triangle
    /// within its allowed distance, if any: one query of the triangle grid
    /// per leaf, the first triangle found (the fast check first tries the
    /// piece the leaf before was found on). Many open leaves (a sequence's
    /// first frame has every leaf open) are searched in two halves on two
    /// threads: on the default job that search took 23 ms, and the
    /// second frame waited for it.
    fn search_leaves(&mut self, meshes: &MeshView<'_>, reference: bool) -> Vec<Option<(u32, u32)>> {
        self.ensure_grid();
        let search = LeafSearch {
            tris: &self.tris,
            boxes: &self.boxes,
            tri_piece: &self.tri_piece,
            piece_starts: &self.piece_starts,
            piece_tris: &self.piece_tris,
            leaf_starts: &self.leaf_starts,
            leaf_vertices: &self.leaf_vertices,
            positions: meshes.leaf_positions,
            grid: &self.grid,
            reference,
        };
        let open = &self.open_leaves;
        if open.len() < PARALLEL_LEAVES {
            return search.run(open);
        }
        let (a, b) = open.split_at(open.len() / 2);
        let (mut hits, rest) = rayon::join(|| search.run(a), || search.run(b));
        hits.extend(rest);
        hits
    }

    /// Settles the open leaves and the open pieces' base vertices in one
    /// pass over the visible triangles ([`Sweep`]).
    fn sweep_open(&mut self, meshes: &MeshView<'_>, reach: f32) -> Found {
        let open = std::mem::take(&mut self.open_leaves);
        let mut points = std::mem::take(&mut self.open_points);
        points.clear();
        let mut spans = Vec::with_capacity(open.len());
        for o in &open {
            let (lo, hi) = self.leaf_points(meshes, o.leaf as usize);
            spans.push((points.len(), (lo, hi)));
            points.extend_from_slice(&self.scratch);
        }
        let ends = spans.iter().skip(1).map(|s| s.0).chain([points.len()]);
        let leaves: Vec<LeafQuestion<'_>> = spans
            .iter()
            .zip(ends)
            .zip(&open)
            .map(|(((start, bounds), end), o)| LeafQuestion {
                points: &points[*start..end],
                bounds: *bounds,
                allowed: o.allowed,
            })
            .collect();
        let vertices = self.base_vertices(meshes);
        self.bound_pieces();
        let triangles = Triangles {
            tris: &self.tris,
            boxes: &self.boxes,
            piece: &self.tri_piece,
            starts: &self.piece_starts,
            by_piece: &self.piece_tris,
            piece_boxes: &self.piece_boxes,
        };
        let questions = (&leaves[..], &vertices[..], self.open_pieces.len());
        let found = self
            .sweep
            .run(self.frame_bounds, triangles, questions, reach);
        drop(leaves);
        self.open_points = points;
        self.open_leaves = open;
        found
    }

    /// The first visible vertices of each open piece (for a tube, its base
    /// ring), as questions of the sweep.
    fn base_vertices(&self, meshes: &MeshView<'_>) -> Vec<VertexQuestion> {
        let mut questions = Vec::new();
        for (rank, &piece) in self.open_pieces.iter().enumerate() {
            let verts = self.piece_vert_starts[piece as usize] as usize
                ..self.piece_vert_starts[piece as usize + 1] as usize;
            let visible = self.piece_verts[verts]
                .iter()
                .filter(|&&v| self.vertex_visible[v as usize]);
            questions.extend(visible.take(BASE_VERTICES).map(|&v| VertexQuestion {
                rank: rank as u32,
                piece,
                vertex: v,
                at: meshes.branch_positions[v as usize],
            }));
        }
        questions
    }

    /// Keeps the proofs `hits` found for the open leaves, reports those
    /// with none as floating, and measures their gaps.
    fn settle_leaves(
        &mut self,
        meshes: &MeshView<'_>,
        options: &PlausibilityOptions,
        hits: Vec<Option<(u32, u32)>>,
        reference: bool,
        report: &mut Report,
    ) {
        for (o, hit) in self.open_leaves.iter().zip(hits) {
            match hit {
                Some((k, t)) if !reference => {
                    self.leaf_proof[o.leaf as usize] = (k, self.tri_orig[t as usize]);
                }
                Some(_) => {}
                None => report.floating.push(FloatingLeaf {
                    leaf: o.leaf,
                    gap: f32::NAN,
                    allowed: o.allowed,
                    size: o.size,
                }),
            }
        }
        report.floating_leaves = report.floating.len() as u32;
        if report.floating.is_empty() {
            return;
        }
        if options.exact_gaps {
            self.exact_gaps(meshes, reference, report);
            report.worst_leaf_gap = report.floating.iter().map(|f| f.gap).fold(0.0, f32::max);
        } else {
            report.worst_leaf_gap = f32::NAN;
        }
    }

    /// Exact distance from each floating leaf to the branch surface: a k-d
    /// tree over the centroids of all but the largest 1 % of triangles
    /// (by circumradius about the centroid) gives an upper bound from a few
    /// vertices' nearest centroids; every triangle that could beat it has
    /// its centroid within bound + leaf radius + that circumradius of the
    /// leaf's centre; the largest triangles are tested one by one, those
    /// whose bounds are no nearer than the best so far skipped.
    fn exact_gaps(&mut self, meshes: &MeshView<'_>, reference: bool, report: &mut Report) {
        if self.tris.is_empty() {
            for f in &mut report.floating {
                f.gap = f32::INFINITY;
            }
            return;
        }
        let radius = |t: &[Vec3; 3]| {
            let c = (t[0] + t[1] + t[2]) / 3.0;
            t.iter().map(|v| v.distance(c)).fold(0.0, f32::max)
        };
        let mut radii: Vec<f32> = self.tris.iter().map(radius).collect();
        let k = (radii.len() * 99 / 100).min(radii.len() - 1);
        let small_r = *radii.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1;
        let mut small: Vec<u32> = Vec::new();
        let mut big: Vec<u32> = Vec::new();
        let mut centroids: Vec<[f32; 3]> = Vec::new();
        for (i, t) in self.tris.iter().enumerate() {
            if radius(t) <= small_r {
                small.push(i as u32);
                centroids.push(((t[0] + t[1] + t[2]) / 3.0).to_array());
            } else {
                big.push(i as u32);
            }
        }
        let index: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&centroids);
        for f in &mut report.floating {
            let leaf = f.leaf as usize;
            let vs = &self.leaf_vertices
                [self.leaf_starts[leaf] as usize..self.leaf_starts[leaf + 1] as usize];
            let pts: Vec<Vec3> = vs
                .iter()
                .map(|&v| meshes.leaf_positions[v as usize])
                .collect();
            let nearest = |p: Vec3, best: f32, t: u32| {
                // Bounds no nearer than the best so far cannot beat it.
                if !reference && box_gap_sq((p, p), self.boxes[t as usize]) >= best {
                    return best;
                }
                best.min(point_triangle_sq(p, self.tris[t as usize]))
            };
            let mut best = f32::INFINITY;
            // Any triangle gives an upper bound; the nearest centroid to a
            // few vertices (every fourth) gives a tight one cheaply.
            for (k, &p) in pts.iter().enumerate() {
                if reference || k % 4 == 0 {
                    let n = index.nearest_one::<SquaredEuclidean>(&p.to_array());
                    best = best.min(point_triangle_sq(
                        p,
                        self.tris[small[n.item as usize] as usize],
                    ));
                }
            }
            let (mut lo, mut hi) = (pts[0], pts[0]);
            for &p in &pts {
                lo = lo.min(p);
                hi = hi.max(p);
            }
            for &t in &big {
                // Bounds no nearer than the best so far cannot beat it.
                if !reference && box_gap_sq((lo, hi), self.boxes[t as usize]) >= best {
                    continue;
                }
                for &p in &pts {
                    best = nearest(p, best, t);
                }
            }
            let centre = pts.iter().copied().sum::<Vec3>() / pts.len() as f32;
            let rho = pts.iter().map(|p| p.distance(centre)).fold(0.0, f32::max);
            let reach = best.sqrt() + rho + small_r;
            for n in index.within_unsorted::<SquaredEuclidean>(&centre.to_array(), reach * reach) {
                let t = small[n.item as usize];
                // Most candidates lie in a shell around the leaf: their
                // bounds alone rule them out.
                if box_gap_sq((lo, hi), self.boxes[t as usize]) >= best {
                    continue;
                }
                for &p in &pts {
                    best = nearest(p, best, t);
                }
            }
            f.gap = best.sqrt();
        }
    }

    /// Pieces other than the root not settled by a shortcut, into
    /// `open_pieces` (every one in the reference); counts the visible
    /// pieces.
    fn open_pieces(
        &mut self,
        meshes: &MeshView<'_>,
        reach: f32,
        reference: bool,
        report: &mut Report,
    ) {
        let root = self.root;
        let mut open = std::mem::take(&mut self.open_pieces);
        open.clear();
        for piece in 0..self.pieces {
            if self.piece_starts[piece] == self.piece_starts[piece + 1] {
                continue;
            }
            report.branch_pieces += 1;
            if root != Some(piece as u32)
                && (reference || !self.piece_settled(meshes, piece as u32, reach))
            {
                open.push(piece as u32);
            }
        }
        self.open_pieces = open;
    }

    /// Keeps the proofs `hits` found for the open pieces, searches the
    /// rest exhaustively and reports those near no other piece.
    fn settle_pieces(
        &mut self,
        meshes: &MeshView<'_>,
        hits: Vec<Option<(u32, u32)>>,
        reach: f32,
        reference: bool,
        report: &mut Report,
    ) {
        let open = std::mem::take(&mut self.open_pieces);
        for (&piece, hit) in open.iter().zip(hits) {
            let near = match hit {
                Some((v, t)) => {
                    self.partner[piece as usize] = Partner::Vertex(v, self.tri_orig[t as usize]);
                    true
                }
                None => {
                    self.ensure_grid();
                    if reference {
                        self.piece_near_exact(piece, reach, false)
                    } else {
                        self.piece_near(meshes, piece, reach)
                    }
                }
            };
            if !near {
                let list = self.piece_starts[piece as usize] as usize
                    ..self.piece_starts[piece as usize + 1] as usize;
                let (tris, list) = (&self.tris, &self.piece_tris[list]);
                let first = list
                    .iter()
                    .flat_map(|&t| tris[t as usize])
                    .fold(Vec3::INFINITY, |a, v| if v.y < a.y { v } else { a });
                report.floating_pieces.push(FloatingPiece {
                    first_vertex: self.piece_first[piece as usize],
                    triangles: list.len() as u32,
                    lowest: first,
                });
            }
        }
        self.open_pieces = open;
        report.floating_branches = report.floating_pieces.len() as u32;
    }

    /// Whether `piece` comes within `reach` of another piece by a
    /// shortcut: last frame's proof, else a vertex of the piece within
    /// reach of a triangle of the piece that proof named (a child tube
    /// stays on its parent while both move). Keeps a new proof.
    fn piece_settled(&mut self, meshes: &MeshView<'_>, piece: u32, reach: f32) -> bool {
        let reach2 = reach * reach;
        let positions = meshes.branch_positions;
        let visible = |t: u32| match self.visible_of.get(t as usize) {
            Some(&v) if v != u32::MAX => Some(v),
            _ => None,
        };
        match self.partner[piece as usize] {
            Partner::None => {}
            Partner::Vertex(v, t) => {
                if self.vertex_visible[v as usize]
                    && let Some(s) = visible(t)
                    && point_triangle_sq(positions[v as usize], self.tris[s as usize]) <= reach2
                {
                    return true;
                }
            }
            Partner::Triangles(a, b) => {
                if let (Some(a), Some(b)) = (visible(a), visible(b))
                    && triangle_triangle_sq(self.tris[a as usize], self.tris[b as usize]) <= reach2
                {
                    return true;
                }
            }
        }
        // The piece its proof named, else its neighbours' (strands are
        // numbered so that siblings, which grow from one parent, are
        // neighbours: a piece just grown, with no proof yet, mostly
        // starts inside the piece its neighbour's proof names).
        let host = self.host_pieces().get(piece as usize).copied();
        let hints = [
            self.partner_piece(piece),
            piece.checked_sub(1).and_then(|p| self.partner_piece(p)),
            self.partner_piece(piece + 1),
            host.filter(|&h| h != u32::MAX),
        ];
        for (i, other) in hints.into_iter().enumerate() {
            if let Some(other) = other
                && other != piece
                && !hints[..i].contains(&Some(other))
                && let Some((v, t)) = self.base_near(positions, piece, other, reach2)
            {
                self.partner[piece as usize] = Partner::Vertex(v, self.tri_orig[t as usize]);
                return true;
            }
        }
        false
    }

    /// The piece the proof of `piece` names, if it has one.
    fn partner_piece(&self, piece: u32) -> Option<u32> {
        let t = match *self.partner.get(piece as usize)? {
            Partner::None => return None,
            Partner::Vertex(_, t) | Partner::Triangles(_, t) => t,
        };
        let &v = self.branch_key.get(3 * t as usize)?;
        Some(self.piece_of[v as usize])
    }

    /// A base vertex of `piece` (one of its first visible ones) and a
    /// visible triangle of `other` within `reach2` of it.
    fn base_near(
        &self,
        positions: &[Vec3],
        piece: u32,
        other: u32,
        reach2: f32,
    ) -> Option<(u32, u32)> {
        let verts = self.piece_vert_starts[piece as usize] as usize
            ..self.piece_vert_starts[piece as usize + 1] as usize;
        let tris = self.piece_starts[other as usize] as usize
            ..self.piece_starts[other as usize + 1] as usize;
        let base = self.piece_verts[verts]
            .iter()
            .filter(|&&v| self.vertex_visible[v as usize])
            .take(BASE_VERTICES);
        for &v in base {
            let p = positions[v as usize];
            let hit = self.piece_tris[tris.clone()].iter().find(|&&t| {
                box_gap_sq((p, p), self.boxes[t as usize]) <= reach2
                    && point_triangle_sq(p, self.tris[t as usize]) <= reach2
            });
            if let Some(&t) = hit {
                return Some((v, t));
            }
        }
        None
    }

    /// Whether `piece` comes within `reach` of another piece: the exact
    /// answer of [`Plausibility::piece_near_exact`], reached sooner by a
    /// sufficient test first — a vertex of the piece within reach of
    /// another piece's triangle (a vertex of a visible triangle lies on
    /// the piece's surface, so the surfaces come within that distance).
    fn piece_near(&mut self, meshes: &MeshView<'_>, piece: u32, reach: f32) -> bool {
        let positions = meshes.branch_positions;
        let verts = self.piece_vert_starts[piece as usize] as usize
            ..self.piece_vert_starts[piece as usize + 1] as usize;
        for k in verts {
            let v = self.piece_verts[k];
            if !self.vertex_visible[v as usize] {
                continue;
            }
            let p = positions[v as usize];
            let hit = self.other_near(piece, (p, p), reach, |t| point_triangle_sq(p, t));
            if let Some(hit) = hit {
                self.partner[piece as usize] = Partner::Vertex(v, self.tri_orig[hit as usize]);
                return true;
            }
        }
        self.piece_near_exact(piece, reach, true)
    }

    /// Whether `piece` comes within `reach` of another piece: every pair of
    /// its visible triangles and another piece's within the reach's
    /// bounds, by exact triangle–triangle distance, until one is close
    /// enough. Keeps the pair as the piece's proof when `remember`.
    fn piece_near_exact(&mut self, piece: u32, reach: f32, remember: bool) -> bool {
        let list = self.piece_starts[piece as usize] as usize
            ..self.piece_starts[piece as usize + 1] as usize;
        for k in list {
            let t = self.piece_tris[k];
            let tri = self.tris[t as usize];
            let hit = self.other_near(piece, self.boxes[t as usize], reach, |s| {
                triangle_triangle_sq(tri, s)
            });
            if let Some(hit) = hit {
                if remember {
                    self.partner[piece as usize] =
                        Partner::Triangles(self.tri_orig[t as usize], self.tri_orig[hit as usize]);
                }
                return true;
            }
        }
        false
    }

    /// The first triangle of a piece other than `piece` within `reach` of
    /// the box `bounds` and, by the squared distance `dist` to it, of the
    /// geometry the box holds.
    fn other_near(
        &mut self,
        piece: u32,
        bounds: (Vec3, Vec3),
        reach: f32,
        dist: impl Fn([Vec3; 3]) -> f32,
    ) -> Option<u32> {
        let reach2 = reach * reach;
        let (tris, boxes, tri_piece) = (&self.tris, &self.boxes, &self.tri_piece);
        let mut hit = None;
        self.grid.any_near(bounds.0 - reach, bounds.1 + reach, |s| {
            let near = tri_piece[s as usize] != piece
                && box_gap_sq(bounds, boxes[s as usize]) <= reach2
                && dist(tris[s as usize]) <= reach2;
            if near {
                hit = Some(s);
            }
            near
        });
        hit
    }
}
