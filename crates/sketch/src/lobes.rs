//! Step 2 of the baseline transformation (§5.3): the lobes deform with
//! their cages.
//!
//! Every cage's lobe — its 3D hull mesh — gets a Laplacian deformation
//! (Eq. 1) in the view plane: the hull vertices on the silhouette (the cage
//! vertices) are hard constraints at their cage's position; the other
//! vertices keep their Laplacian coordinates in the least-squares sense, at
//! their rest depth. Weights are cotangent weights of the rest mesh, clamped
//! at zero and each row normalised by its sum: convex hulls of leaf points
//! have sliver triangles whose negative or huge cotangents would otherwise
//! dominate. One block-diagonal system over every lobe is factorised the
//! first time lobes are asked for and reused for every frame after.
//!
//! Branches and leaves do not depend on this: leaves ride on their chains.
//! Deformed lobes are what a viewer draws to show the cages at work.

use std::sync::OnceLock;

use glam::{Vec2, Vec3};
use treemorph_analysis::{Analysis, Hull};
use treemorph_tree::geom::NONE;

use crate::error::SketchError;
use crate::laplacian::{COLS, LeastSquares, scratch_for};
use crate::mct::{CageKind, Mct};
use crate::view::Camera;

/// The lobe meshes of every cage and, once built, their factorised system.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct LobeSource {
    /// Per cage: first vertex / first triangle (one past the last cage: the
    /// totals).
    vertex_offsets: Vec<usize>,
    triangle_offsets: Vec<usize>,
    vertices: Vec<Vec3>,
    depth: Vec<f32>,
    /// Cage-local triangles.
    triangles: Vec<[u32; 3]>,
    /// Per vertex: the flat cage-vertex index constraining it, or NONE.
    constraint: Vec<u32>,
    #[serde(skip)]
    system: OnceLock<Result<LobeSystem, SketchError>>,
}

#[derive(Debug)]
pub(crate) struct LobeSystem {
    ls: LeastSquares,
    /// The vertex each unknown is.
    unknowns: Vec<u32>,
    /// `(row, constrained vertex, coefficient)`: `b[row] += coef × d`.
    rhs: Vec<(u32, u32, f32)>,
}

fn hull_of(analysis: &Analysis, kind: CageKind, group: Option<u32>, chain: Option<u32>) -> &Hull {
    match (kind, group, chain) {
        (CageKind::Crown, _, _) => &analysis.crown().hull,
        (CageKind::GroupOuter, Some(g), _) => &analysis.group(g).outer_lobe.hull,
        (CageKind::Outer, _, Some(c)) => &analysis.chain(c).outer_lobe.hull,
        (CageKind::Inner, _, Some(c)) => &analysis.chain(c).inner_lobe.hull,
        _ => &analysis.crown().hull,
    }
}

impl LobeSource {
    /// Collects the lobe meshes of the cages of `mct`.
    pub(crate) fn new(analysis: &Analysis, mct: &Mct, camera: &Camera) -> LobeSource {
        let mut s = LobeSource::default();
        s.vertex_offsets.push(0);
        s.triangle_offsets.push(0);
        for cage in &mct.cages {
            let hull = hull_of(analysis, cage.kind, cage.group, cage.chain);
            let base = s.vertices.len();
            s.vertices.extend_from_slice(&hull.vertices);
            s.depth
                .extend(hull.vertices.iter().map(|&v| camera.depth(v)));
            s.triangles.extend_from_slice(&hull.triangles);
            s.constraint.resize(s.vertices.len(), NONE);
            for (k, &hv) in cage.hull_vertex.iter().enumerate() {
                if hv != NONE && (hv as usize) < hull.vertices.len() {
                    s.constraint[base + hv as usize] = (cage.offset + k) as u32;
                }
            }
            s.vertex_offsets.push(s.vertices.len());
            s.triangle_offsets.push(s.triangles.len());
        }
        s
    }

    pub(crate) fn system(&self) -> Result<&LobeSystem, SketchError> {
        self.system
            .get_or_init(|| self.build())
            .as_ref()
            .map_err(Clone::clone)
    }

    fn build(&self) -> Result<LobeSystem, SketchError> {
        let n = self.vertices.len();
        let mut unknown = vec![NONE; n];
        let mut unknowns = Vec::new();
        for (v, slot) in unknown.iter_mut().enumerate() {
            if self.constraint[v] == NONE {
                *slot = unknowns.len() as u32;
                unknowns.push(v as u32);
            }
        }
        let mut entries: Vec<(usize, usize, f64)> = Vec::new();
        let mut rhs: Vec<(u32, u32, f32)> = Vec::new();
        let mut rows = 0usize;
        let cages = self.vertex_offsets.len() - 1;
        let mut weights: Vec<Vec<(u32, f64)>> = Vec::new();
        for c in 0..cages {
            let (v0, v1) = (self.vertex_offsets[c], self.vertex_offsets[c + 1]);
            weights.clear();
            weights.resize(v1 - v0, Vec::new());
            for t in &self.triangles[self.triangle_offsets[c]..self.triangle_offsets[c + 1]] {
                for k in 0..3 {
                    // The angle at t[k] is opposite the edge t[k+1]–t[k+2].
                    let (o, a, b) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                    let (po, pa, pb) = (
                        self.vertices[v0 + o as usize].as_dvec3(),
                        self.vertices[v0 + a as usize].as_dvec3(),
                        self.vertices[v0 + b as usize].as_dvec3(),
                    );
                    let (ea, eb) = (pa - po, pb - po);
                    let cross = ea.cross(eb).length();
                    let cot = if cross > 0.0 { ea.dot(eb) / cross } else { 0.0 };
                    let w = 0.5 * cot.clamp(0.0, 1e3) + 1e-6;
                    weights[a as usize].push((b, w));
                    weights[b as usize].push((a, w));
                }
            }
            for (i, nbrs) in weights.iter_mut().enumerate() {
                nbrs.sort_by_key(|&(j, _)| j);
                nbrs.dedup_by(|x, y| {
                    if x.0 == y.0 {
                        y.1 += x.1;
                        true
                    } else {
                        false
                    }
                });
                let total: f64 = nbrs.iter().map(|&(_, w)| w).sum();
                if total <= 0.0 {
                    continue;
                }
                let vi = v0 + i;
                let has_unknown = unknown[vi] != NONE
                    || nbrs.iter().any(|&(j, _)| unknown[v0 + j as usize] != NONE);
                if !has_unknown {
                    continue;
                }
                let row = rows;
                rows += 1;
                let mut term = |v: usize, coef: f64| {
                    if unknown[v] != NONE {
                        entries.push((row, unknown[v] as usize, coef));
                    } else {
                        rhs.push((row as u32, v as u32, -coef as f32));
                    }
                };
                term(vi, 1.0);
                for &(j, w) in nbrs.iter() {
                    term(v0 + j as usize, -w / total);
                }
            }
        }
        let ls = LeastSquares::new(unknowns.len(), rows, &entries)?;
        Ok(LobeSystem { ls, unknowns, rhs })
    }
}

/// Per-frame buffers of the lobe deformation.
pub(crate) struct LobeBuffers {
    disp: Vec<Vec2>,
    positions: Vec<Vec3>,
    b: Vec<[f64; COLS]>,
    x: faer::Mat<f64>,
    mem: Option<faer::dyn_stack::MemBuffer>,
}

impl Default for LobeBuffers {
    fn default() -> LobeBuffers {
        LobeBuffers {
            disp: Vec::new(),
            positions: Vec::new(),
            b: Vec::new(),
            x: faer::Mat::zeros(0, 0),
            mem: None,
        }
    }
}

/// The deformed lobes of one frame: per cage, its hull mesh.
pub struct DeformedLobes<'a> {
    source: &'a LobeSource,
    positions: &'a [Vec3],
}

impl DeformedLobes<'_> {
    /// Number of cages (indexed like [`crate::SketchPlan::cages`]).
    pub fn len(&self) -> usize {
        self.source.vertex_offsets.len() - 1
    }

    /// Whether there are no cages.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The deformed vertices of cage `i`'s lobe, metres.
    pub fn vertices(&self, i: usize) -> &[Vec3] {
        &self.positions[self.source.vertex_offsets[i]..self.source.vertex_offsets[i + 1]]
    }

    /// The rest vertices of cage `i`'s lobe, metres.
    pub fn rest_vertices(&self, i: usize) -> &[Vec3] {
        &self.source.vertices[self.source.vertex_offsets[i]..self.source.vertex_offsets[i + 1]]
    }

    /// The triangles of cage `i`'s lobe (indices into its vertices).
    pub fn triangles(&self, i: usize) -> &[[u32; 3]] {
        &self.source.triangles[self.source.triangle_offsets[i]..self.source.triangle_offsets[i + 1]]
    }
}

impl LobeBuffers {
    /// The lobes deformed by the cage displacements `cage_disp` (flat, per
    /// cage vertex) with `system`, the factorised system of `source`.
    pub(crate) fn deform<'a>(
        &'a mut self,
        source: &'a LobeSource,
        system: &LobeSystem,
        cage_disp: &[Vec2],
        camera: &Camera,
    ) -> DeformedLobes<'a> {
        let n = source.vertices.len();
        self.disp.clear();
        self.disp.resize(n, Vec2::ZERO);
        for v in 0..n {
            let c = source.constraint[v];
            if c != NONE {
                self.disp[v] = cage_disp[c as usize];
            }
        }
        self.b.clear();
        self.b.resize(system.ls.rows(), [0.0; COLS]);
        for &(row, v, coef) in &system.rhs {
            let d = self.disp[v as usize];
            let r = &mut self.b[row as usize];
            r[0] += f64::from(coef * d.x);
            r[1] += f64::from(coef * d.y);
        }
        let mem = self.mem.get_or_insert_with(|| scratch_for([&system.ls]));
        system.ls.solve(&self.b, &mut self.x, mem);
        for (k, &v) in system.unknowns.iter().enumerate() {
            self.disp[v as usize] = Vec2::new(self.x[(k, 0)] as f32, self.x[(k, 1)] as f32);
        }
        self.positions.clear();
        self.positions.extend(
            source
                .vertices
                .iter()
                .zip(&self.disp)
                .zip(&source.depth)
                .map(|((&p, &d), &z)| p + camera.world_delta(d, z)),
        );
        DeformedLobes {
            source,
            positions: &self.positions,
        }
    }
}
