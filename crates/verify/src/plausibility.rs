//! The plausibility check: [`Plausibility`], its input [`MeshView`], its
//! [`PlausibilityOptions`] and its [`Report`].

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use thiserror::Error;
use treemorph_gltf::frames::FrameMeshes;
use treemorph_gltf::mesh::{LeafShape, MeshBuffers};

use crate::geometry::{point_triangle_sq, triangle_triangle_sq};
use crate::grid::TriangleGrid;

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

fn check_mesh(mesh: &'static str, positions: &[Vec3], indices: &[u32]) -> Result<(), VerifyError> {
    if !indices.len().is_multiple_of(3) {
        return Err(VerifyError::NotTriangles {
            mesh,
            count: indices.len(),
        });
    }
    if let Some(&index) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(VerifyError::IndexOutOfRange {
            mesh,
            index,
            vertices: positions.len(),
        });
    }
    if let Some(vertex) = positions.iter().position(|p| !p.is_finite()) {
        return Err(VerifyError::NotFinite { mesh, vertex });
    }
    Ok(())
}

fn box_gap_sq((alo, ahi): (Vec3, Vec3), (blo, bhi): (Vec3, Vec3)) -> f32 {
    let d = (blo - ahi).max(alo - bhi).max(Vec3::ZERO);
    d.length_squared()
}

impl Plausibility {
    /// A context with empty buffers.
    pub fn new() -> Plausibility {
        Plausibility::default()
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
        check_mesh("branch", meshes.branch_positions, meshes.branch_indices)?;
        check_mesh("leaf", meshes.leaf_positions, meshes.leaf_indices)?;
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for &p in meshes.branch_positions.iter().chain(meshes.leaf_positions) {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let height = if lo.y <= hi.y { hi.y - lo.y } else { 0.0 };
        let diagonal = if lo.x <= hi.x {
            (hi - lo).length()
        } else {
            0.0
        };

        self.label_pieces(meshes);
        self.group_leaves(meshes)?;
        self.collect_triangles(meshes);
        // Cells of about the branch reach (and twice a typical leaf's
        // allowance): a query spans a cell or two each way, and a thin
        // tube's triangle sits in one or two cells, which keeps the build
        // (the bulk of a clean frame's cost) short; bounded below so a
        // flat or tiny frame stays sane.
        let cell = (0.02 * height).max(diagonal / 1024.0).max(1e-6);
        self.grid.build(&self.boxes, cell);

        let mut report = Report {
            height,
            ..Report::default()
        };
        self.check_leaves(meshes, options, height, reference, &mut report);
        self.check_pieces(meshes, options, height, reference, &mut report);
        Ok(report)
    }

    /// Labels branch vertices by connected component, unless the index
    /// buffer is the one labelled last time.
    fn label_pieces(&mut self, meshes: &MeshView<'_>) {
        let n = meshes.branch_positions.len();
        if self.branch_vertices == n && self.branch_key == meshes.branch_indices {
            return;
        }
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
    }

    /// Groups leaf vertices into leaves, unless nothing changed.
    fn group_leaves(&mut self, meshes: &MeshView<'_>) -> Result<(), VerifyError> {
        let n = meshes.leaf_positions.len();
        let key = (meshes.leaves, n);
        let same_indices = self.leaf_key == meshes.leaf_indices;
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
    /// and bounds, and lists them by piece.
    fn collect_triangles(&mut self, meshes: &MeshView<'_>) {
        self.tris.clear();
        self.tri_piece.clear();
        self.boxes.clear();
        self.tri_orig.clear();
        self.visible_of.clear();
        self.vertex_visible.clear();
        self.vertex_visible
            .resize(meshes.branch_positions.len(), false);
        let p = meshes.branch_positions;
        for (i, t) in meshes.branch_indices.chunks_exact(3).enumerate() {
            let tri = [p[t[0] as usize], p[t[1] as usize], p[t[2] as usize]];
            if (tri[1] - tri[0]).cross(tri[2] - tri[0]).length_squared() <= 0.0 {
                self.visible_of.push(u32::MAX);
                continue;
            }
            self.visible_of.push(self.tris.len() as u32);
            self.tri_orig.push(i as u32);
            for &v in t {
                self.vertex_visible[v as usize] = true;
            }
            self.tris.push(tri);
            self.tri_piece.push(self.piece_of[t[0] as usize]);
            self.boxes.push((
                tri[0].min(tri[1]).min(tri[2]),
                tri[0].max(tri[1]).max(tri[2]),
            ));
        }
        self.piece_starts.clear();
        self.piece_starts.resize(self.pieces + 1, 0);
        for &piece in &self.tri_piece {
            self.piece_starts[piece as usize + 1] += 1;
        }
        for i in 0..self.pieces {
            self.piece_starts[i + 1] += self.piece_starts[i];
        }
        self.piece_tris.clear();
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

    fn check_leaves(
        &mut self,
        meshes: &MeshView<'_>,
        options: &PlausibilityOptions,
        height: f32,
        reference: bool,
        report: &mut Report,
    ) {
        let slack = options.leaf_slack * height;
        let leaf_count = self.leaf_starts.len() - 1;
        for leaf in 0..leaf_count {
            let vs = &self.leaf_vertices
                [self.leaf_starts[leaf] as usize..self.leaf_starts[leaf + 1] as usize];
            self.scratch.clear();
            self.scratch
                .extend(vs.iter().map(|&v| meshes.leaf_positions[v as usize]));
            let pts = &self.scratch;
            let mut size2 = 0.0f32;
            for (i, a) in pts.iter().enumerate() {
                for b in &pts[i + 1..] {
                    size2 = size2.max(a.distance_squared(*b));
                }
            }
            if size2 <= 0.0 {
                continue;
            }
            report.leaves += 1;
            let size = size2.sqrt();
            let allowed = 0.5 * size + slack;
            let allowed2 = allowed * allowed;
            let (mut lo, mut hi) = (pts[0], pts[0]);
            for &p in pts.iter() {
                lo = lo.min(p);
                hi = hi.max(p);
            }
            let (tris, boxes) = (&self.tris, &self.boxes);
            // Last frame's proof first: a vertex within reach of a triangle
            // that is still visible settles it at once.
            if !reference
                && let Some(&(k, t)) = self.leaf_proof.get(leaf)
                && let Some(&s) = self.visible_of.get(t as usize)
                && s != u32::MAX
                && (k as usize) < pts.len()
                && point_triangle_sq(pts[k as usize], tris[s as usize]) <= allowed2
            {
                continue;
            }
            let mut proof = None;
            let attached = self.grid.any_near(lo - allowed, hi + allowed, |t| {
                let b = boxes[t as usize];
                if box_gap_sq((lo, hi), b) > allowed2 {
                    return false;
                }
                let tri = tris[t as usize];
                // A vertex's gap to the triangle's bounds is cheap and
                // rules most vertices out before the exact distance.
                let hit = pts.iter().position(|&p| {
                    (reference || box_gap_sq((p, p), b) <= allowed2)
                        && point_triangle_sq(p, tri) <= allowed2
                });
                if let Some(k) = hit {
                    proof = Some((k as u32, t));
                }
                hit.is_some()
            });
            if let Some((k, t)) = proof
                && !reference
            {
                if self.leaf_proof.len() != leaf_count {
                    self.leaf_proof.clear();
                    self.leaf_proof.resize(leaf_count, (u32::MAX, u32::MAX));
                }
                self.leaf_proof[leaf] = (k, self.tri_orig[t as usize]);
            }
            if !attached {
                report.floating.push(FloatingLeaf {
                    leaf: leaf as u32,
                    gap: f32::NAN,
                    allowed,
                    size,
                });
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

    fn check_pieces(
        &mut self,
        meshes: &MeshView<'_>,
        options: &PlausibilityOptions,
        height: f32,
        reference: bool,
        report: &mut Report,
    ) {
        let reach = options.branch_reach * height;
        // The root piece holds the lowest vertex of a visible triangle.
        let mut root = None;
        let mut lowest = f32::INFINITY;
        for (t, &piece) in self.tris.iter().zip(&self.tri_piece) {
            for v in t {
                if v.y < lowest {
                    lowest = v.y;
                    root = Some(piece);
                }
            }
        }
        for piece in 0..self.pieces {
            let (start, end) = (
                self.piece_starts[piece] as usize,
                self.piece_starts[piece + 1] as usize,
            );
            if start == end {
                continue;
            }
            report.branch_pieces += 1;
            if root == Some(piece as u32) {
                continue;
            }
            let near = if reference {
                self.piece_near_exact(piece as u32, reach, false)
            } else {
                self.piece_near(meshes, piece as u32, reach)
            };
            if !near {
                let (tris, list) = (&self.tris, &self.piece_tris[start..end]);
                let first = list
                    .iter()
                    .flat_map(|&t| tris[t as usize])
                    .fold(Vec3::INFINITY, |a, v| if v.y < a.y { v } else { a });
                report.floating_pieces.push(FloatingPiece {
                    first_vertex: self.piece_first[piece],
                    triangles: list.len() as u32,
                    lowest: first,
                });
            }
        }
        report.floating_branches = report.floating_pieces.len() as u32;
    }

    /// Whether `piece` comes within `reach` of another piece: the exact
    /// answer of [`Plausibility::piece_near_exact`], reached sooner by
    /// sufficient tests first — last frame's proof, then a vertex of the
    /// piece within reach of another piece's triangle (a vertex of a
    /// visible triangle lies on the piece's surface, so the surfaces come
    /// within that distance). Most child tubes start inside their parent:
    /// their base ring settles it.
    fn piece_near(&mut self, meshes: &MeshView<'_>, piece: u32, reach: f32) -> bool {
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
