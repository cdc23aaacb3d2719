//! The `skinned` animation's part of the document: the bind pose that
//! replaces the base mesh, the residual left to morph targets, the error
//! of what a player shows, and the skeleton's nodes, skin and channels.
//! The skeleton itself is [`super::skin`]'s.
//!
//! # Dissolves without node scale
//! glTF ignores a skinned mesh node's own transform, so the basis
//! animation's swap nodes (scaled to 0 when hidden) cannot hide skinned
//! meshes. Instead every swapping node's vertex set carries one more
//! morph target, `hidden`, that folds each leaf into its centre and each
//! bark ring into its axis: at weight 1 the node draws nothing. Its weight
//! switches within a millisecond at the swap time (an extra key just
//! before it), as the basis animation's STEP scale does.

use glam::{Vec3, Vec4};
use rayon::prelude::*;
use serde_json::{Value, json};
use treemorph_tree::NodeId;

use super::motion::{Columns, Principal};
use super::skin::{self, Bind, Poses, Rig, Samples};
use super::{BasePose, StoredTarget, Targets, quantised_target};
use crate::animated::{Attr, Writer, f32_bytes, quantise, quantise_normal};
use crate::doc::{Data, Doc};
use crate::frames::EncodeError;
use crate::gl::FLOAT;

/// The largest vertex error a skinned animation aims for, as a fraction
/// of the tree's height: what a few hundred bones and a few residual
/// targets reach on a morph between two different trees.
pub const SKIN_ERROR_BUDGET: f32 = 0.01;

/// How much above the error of all its residual targets a skinned
/// animation short of its budget accepts, to carry fewer targets.
const SKIN_TARGET_SLACK: f32 = 1.1;

/// Vertices per block of [`Skin::worst`]'s parallel pass.
const WORST_BLOCK: usize = 2048;

/// Seconds before a swap at which the `hidden` weight still has its old
/// value.
const SWAP_EDGE: f32 = 1e-3;

/// What the skinned document needs besides the basis' parts.
pub(crate) struct Skin {
    pub(crate) rig: Rig,
    pub(crate) poses: Poses,
    /// The `hidden` target (positions fold, normals stay) as stored, and
    /// the weight that folds it fully.
    pub(crate) hidden: StoredTarget,
    pub(crate) hidden_weight: f32,
    /// Each joint's scale at each sample (`[joint][sample]`): how much of
    /// a residual error a player shows ([`super::weighted`]).
    scales: Vec<Vec<f32>>,
    /// The samples as meshed: the first frame and the columns of
    /// displacements from it (kept to measure the error of the file).
    first: Vec<Vec3>,
    first_normals: Vec<Vec3>,
    displacements: Columns,
    normal_changes: Columns,
}

/// Replaces `base` by the bind pose (each joint bound as `choice` says)
/// and `displacements`/`normal_changes` by the residual in the joints'
/// frames; returns the skeleton.
pub(crate) fn rig_up(
    base: &mut BasePose,
    (displacements, normal_changes): (&mut Columns, &mut Columns),
    owners: &[(u32, NodeId)],
    (rig, choice): (Rig, Bind),
    grid: Option<(Vec3, f32)>,
) -> Result<Skin, EncodeError> {
    let first = std::mem::take(&mut base.positions);
    let first_normals = std::mem::take(&mut base.normals);
    let d = std::mem::take(displacements);
    let nd = std::mem::take(normal_changes);
    let samples = Samples {
        base: &first,
        base_normals: &first_normals,
        displacements: &d,
        normal_changes: &nd,
    };
    let members = rig.members();
    let binds = skin::bind_samples_by(choice, &rig.anchors, &members, &samples);
    let (bind, bind_normals): (Vec<Vec3>, Vec<Vec3>) = rig
        .vertex_joint
        .iter()
        .enumerate()
        .map(|(v, &j)| {
            let f = binds[j as usize];
            (
                samples.position(f, v),
                samples.normal(f, v).normalize_or_zero(),
            )
        })
        .unzip();
    set_pose(base, bind, bind_normals, grid)?;
    let fits = skin::fit_joints(&rig.anchors, &base.positions, &samples);
    let origins = origins(&rig, &members, owners, &base.positions);
    let (r, rn) = skin::residuals(&rig, &fits, &base.positions, &base.normals, &samples);
    *displacements = r;
    *normal_changes = rn;
    let scales = fits
        .iter()
        .map(|j| j.iter().map(|s| s.scale as f32).collect())
        .collect();
    let folds = folds(base, owners);
    let (hidden, hidden_weight) = hidden_target(&folds, grid);
    let poses = skin::poses(&rig, origins, fits);
    Ok(Skin {
        rig,
        poses,
        hidden,
        hidden_weight,
        scales,
        first,
        first_normals,
        displacements: d,
        normal_changes: nd,
    })
}

/// Sets `base`'s positions and normals (and their quantised forms).
fn set_pose(
    base: &mut BasePose,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    grid: Option<(Vec3, f32)>,
) -> Result<(), EncodeError> {
    if let Some((t, s)) = grid {
        base.q_positions = positions
            .iter()
            .map(|&p| quantise(p, t, s))
            .collect::<Option<_>>()
            .ok_or_else(crate::animated::outside)?;
        base.q_normals = normals.iter().map(|&n| quantise_normal(n)).collect();
        base.positions = base
            .q_positions
            .iter()
            .map(|q| t + s * Vec3::from(q.map(f32::from)) / 32_767.0)
            .collect();
        base.normals = base
            .q_normals
            .iter()
            .map(|q| Vec3::from(q.map(f32::from)) / 127.0)
            .collect();
    } else {
        base.positions = positions;
        base.normals = normals;
    }
    Ok(())
}

/// Each joint's node position in the bind pose: the centre of its top
/// strand's base ring (where the chain leaves its parent), else of its
/// vertices; the still root at the origin.
fn origins(rig: &Rig, members: &[Vec<u32>], owners: &[(u32, NodeId)], bind: &[Vec3]) -> Vec<Vec3> {
    let mut first_node: Vec<Option<(u32, NodeId)>> = vec![None; rig.joint_count()];
    for (&(strand, node), &j) in owners.iter().zip(&rig.vertex_joint) {
        if rig.top_strands[j as usize] == Some(strand) && first_node[j as usize].is_none() {
            first_node[j as usize] = Some((strand, node));
        }
    }
    (0..rig.joint_count())
        .map(|j| {
            if rig.parents[j].is_none() {
                return Vec3::ZERO;
            }
            let ring: Vec<Vec3> = match first_node[j] {
                Some(key) => owners
                    .iter()
                    .enumerate()
                    .filter(|(_, o)| **o == key)
                    .map(|(v, _)| bind[v])
                    .collect(),
                None => members[j].iter().map(|&v| bind[v as usize]).collect(),
            };
            mean(&ring)
        })
        .collect()
}

fn mean(points: &[Vec3]) -> Vec3 {
    if points.is_empty() {
        return Vec3::ZERO;
    }
    points.iter().copied().sum::<Vec3>() / points.len() as f32
}

/// Per vertex, the offset that folds it away: bark vertices onto their
/// ring's centre, leaf vertices onto their leaf's.
fn folds(base: &BasePose, owners: &[(u32, NodeId)]) -> Vec<Vec3> {
    let p = &base.positions;
    let mut centres: std::collections::HashMap<(u32, NodeId), (Vec3, u32)> = Default::default();
    for (v, o) in owners.iter().enumerate() {
        let e = centres.entry(*o).or_insert((Vec3::ZERO, 0));
        e.0 += p[v];
        e.1 += 1;
    }
    let bark = owners.iter().enumerate().map(|(v, o)| {
        let (sum, n) = centres[o];
        sum / n as f32 - p[v]
    });
    let leaves = &p[base.branch_vertices..];
    let per = base.per_leaf.max(1);
    let leaf = leaves.chunks(per).flat_map(|quad| {
        let c = mean(quad);
        quad.iter().map(move |&v| c - v)
    });
    bark.chain(leaf).collect()
}

/// The `hidden` target of `folds` in the file's encoding and the weight
/// that applies it fully.
fn hidden_target(folds: &[Vec3], grid: Option<(Vec3, f32)>) -> (StoredTarget, f32) {
    match grid {
        None => (StoredTarget::Float(folds.to_vec(), Vec::new()), 1.0),
        Some((_, s)) => {
            let n = folds.len();
            let mut planar = vec![0f32; 3 * n];
            for (v, f) in folds.iter().enumerate() {
                for a in 0..3 {
                    planar[a * n + v] = f[a];
                }
            }
            let (target, _, scale) = quantised_target(&planar, &[], s);
            (target, scale)
        }
    }
}

impl Skin {
    /// The first sample's vertex positions, as meshed.
    pub(crate) fn first_positions(&self) -> &[Vec3] {
        &self.first
    }

    /// Hands over the samples' columns (displacements, normal changes),
    /// for another rig of the same samples; the skeleton cannot measure
    /// its error until they are back ([`Skin::put_samples`]).
    pub(crate) fn take_samples(&mut self) -> (Columns, Columns) {
        (
            std::mem::take(&mut self.displacements),
            std::mem::take(&mut self.normal_changes),
        )
    }

    /// Takes back the columns [`Skin::take_samples`] handed over.
    pub(crate) fn put_samples(&mut self, (displacements, normal_changes): (Columns, Columns)) {
        self.displacements = displacements;
        self.normal_changes = normal_changes;
    }

    /// The samples as meshed.
    fn samples(&self) -> Samples<'_> {
        Samples {
            base: &self.first,
            base_normals: &self.first_normals,
            displacements: &self.displacements,
            normal_changes: &self.normal_changes,
        }
    }

    /// `k` targets of the residual `d` (normals `nd`) fitted to the error
    /// a player shows through the joints' scales (`None`: see
    /// [`super::weighted::refit`]).
    pub(crate) fn refit(&self, d: &Columns, nd: &Columns, k: usize) -> Option<Principal> {
        let shown = super::weighted::Shown {
            vertex_joint: &self.rig.vertex_joint,
            scales: &self.scales,
        };
        super::weighted::refit(d, nd, &shown, k)
    }

    /// The largest distance of any vertex of any sample, as a player
    /// shows it (locals composed in `f32`, targets as stored), from the
    /// sample as meshed.
    pub(crate) fn max_error(&self, base: &BasePose, targets: &Targets) -> f32 {
        self.worst(base, |f, v| targets.offset_at(f, v))
    }

    /// How many of the residual targets `principal` to keep, and the
    /// error a player then shows: the fewest within `budget` (metres),
    /// or when all of them miss it, the fewest within
    /// [`SKIN_TARGET_SLACK`] of all of them. Each count is measured with
    /// the weights that fit best with its targets alone
    /// ([`Principal::leading_weights`]), through the skeleton, not in the
    /// joints' frames: a residual divided by a small joint scale can span
    /// a target that moves other samples' vertices far more than it
    /// helps.
    ///
    /// The count is found by bisection: the error falls with the count
    /// nearly everywhere (a weighted fit's leading targets are not the
    /// best of their count, so not everywhere), and measuring every
    /// count took as long as the fit. Bisection can pass over a smaller
    /// count that a dip brings within the threshold; it never keeps a
    /// count that misses it unless all of them do.
    pub(crate) fn fewest_that_help(
        &self,
        base: &BasePose,
        principal: &Principal,
        budget: f32,
    ) -> (usize, f32) {
        let error_of = |k: usize| {
            let weights = principal.leading_weights(k);
            self.worst(base, |f, v| {
                (0..k)
                    .map(|t| principal.positions.vertex(t, v) * weights[f * k + t])
                    .sum()
            })
        };
        let all = principal.count;
        let all_error = error_of(all);
        let threshold = if all_error <= budget {
            budget
        } else {
            all_error * SKIN_TARGET_SLACK
        };
        // `hi` meets the threshold; `lo` is the fewest not passed over.
        let (mut lo, mut hi, mut hi_error) = (0, all, all_error);
        while lo < hi {
            let mid = (lo + hi) / 2;
            let error = error_of(mid);
            if error <= threshold {
                (hi, hi_error) = (mid, error);
            } else {
                lo = mid + 1;
            }
        }
        (hi, hi_error)
    }

    /// The largest distance of any vertex of any sample as the skeleton
    /// shows it with the bind pose plus `offset(sample, vertex)`.
    fn worst(&self, base: &BasePose, offset: impl Fn(usize, usize) -> Vec3 + Sync) -> f32 {
        let samples = self.samples();
        debug_assert!(
            samples.count() > 0 || base.positions.is_empty(),
            "the samples were handed over (Skin::take_samples)"
        );
        let mats: Vec<Vec<glam::Mat4>> = (0..samples.count())
            .into_par_iter()
            .map(|f| self.poses.skinning(&self.rig, f))
            .collect();
        // Vertex blocks outside, samples inside: a block's targets stay in
        // cache across the samples instead of being read once per sample.
        let n = base.positions.len();
        (0..n.div_ceil(WORST_BLOCK))
            .into_par_iter()
            .map(|b| {
                let block = b * WORST_BLOCK..((b + 1) * WORST_BLOCK).min(n);
                let mut worst = 0f32;
                for (f, mats) in mats.iter().enumerate() {
                    for v in block.clone() {
                        let m = mats[self.rig.vertex_joint[v] as usize];
                        let bound = base.positions[v] + offset(f, v);
                        worst =
                            worst.max(m.transform_point3(bound).distance(samples.position(f, v)));
                    }
                }
                worst
            })
            .reduce(|| 0f32, f32::max)
    }

    /// Writes the joint nodes, their inverse bind matrices (which undo the
    /// quantisation grid too) and the skin; returns the root joint's node.
    pub(crate) fn write_skeleton(
        &self,
        w: &mut Writer,
        grid: Option<(Vec3, f32)>,
    ) -> (Value, usize) {
        let first = w.doc.nodes.len();
        let n = self.rig.joint_count();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (j, p) in self.rig.parents.iter().enumerate() {
            if let Some(p) = p {
                children[*p].push(first + j);
            }
        }
        for (j, kids) in children.into_iter().enumerate() {
            let l = &self.poses.locals[j][0];
            let mut node = json!({
                "name": joint_name(&self.rig, j),
                "translation": l.translation.to_array(),
                "rotation": l.rotation.to_array(),
                "scale": [l.scale, l.scale, l.scale],
            });
            if !kids.is_empty() {
                node["children"] = json!(kids);
            }
            w.doc.nodes.push(node);
        }
        let (t, s) = grid.unwrap_or((Vec3::ZERO, 1.0));
        let matrices: Vec<f32> = self
            .poses
            .origins
            .iter()
            .flat_map(|o| {
                let m = glam::Mat4::from_cols(
                    Vec4::new(s, 0.0, 0.0, 0.0),
                    Vec4::new(0.0, s, 0.0, 0.0),
                    Vec4::new(0.0, 0.0, s, 0.0),
                    (t - *o).extend(1.0),
                );
                m.to_cols_array()
            })
            .collect();
        let view = w.doc.view(Data::Owned(f32_bytes(&matrices)), None, None);
        let ibm = w.doc.accessor(json!({
            "bufferView": view, "componentType": FLOAT, "count": n, "type": "MAT4",
        }));
        let skin = json!({
            "name": "tree skeleton",
            "joints": (first..first + n).collect::<Vec<_>>(),
            "inverseBindMatrices": ibm,
            "skeleton": first,
        });
        (skin, first)
    }

    /// The joints' translation, rotation and scale channels (LINEAR, a
    /// key per sample), appended to `samplers` and `channels`.
    pub(crate) fn write_channels(
        &self,
        doc: &mut Doc<'static>,
        input: usize,
        first_joint: usize,
        samplers: &mut Vec<Value>,
        channels: &mut Vec<Value>,
    ) {
        for (j, locals) in self.poses.locals.iter().enumerate() {
            if self.rig.parents[j].is_none() {
                continue;
            }
            let t: Vec<f32> = locals
                .iter()
                .flat_map(|l| l.translation.to_array())
                .collect();
            let r: Vec<f32> = locals.iter().flat_map(|l| l.rotation.to_array()).collect();
            let s: Vec<f32> = locals.iter().flat_map(|l| [l.scale; 3]).collect();
            for (path, values, ty) in [
                ("translation", t, "VEC3"),
                ("rotation", r, "VEC4"),
                ("scale", s, "VEC3"),
            ] {
                let count = values.len() / if ty == "VEC4" { 4 } else { 3 };
                let view = doc.view(Data::Owned(f32_bytes(&values)), None, None);
                let output = doc.accessor(json!({
                    "bufferView": view, "componentType": FLOAT, "count": count, "type": ty,
                }));
                samplers
                    .push(json!({ "input": input, "output": output, "interpolation": "LINEAR" }));
                channels.push(json!({
                    "sampler": samplers.len() - 1,
                    "target": { "node": first_joint + j, "path": path },
                }));
            }
        }
    }

    /// JOINTS_0 and WEIGHTS_0 of the vertices at `indices`.
    pub(crate) fn write_influences(&self, w: &mut Writer, indices: &[usize]) -> (usize, usize) {
        let count = indices.len();
        let joints: Vec<u8> = indices
            .iter()
            .flat_map(|&v| [self.rig.vertex_joint[v] as u16, 0, 0, 0])
            .flat_map(u16::to_le_bytes)
            .collect();
        let weights: Vec<u8> = indices.iter().flat_map(|_| [255u8, 0, 0, 0]).collect();
        let joints = super::meshopt_if(w.encoding, joints, 8);
        let weights = super::meshopt_if(w.encoding, weights, 4);
        (
            w.attribute(count, joints, Attr::Joints4U16, None),
            w.attribute(count, weights, Attr::Weights4U8, None),
        )
    }
}

/// A joint's node name: the root, else the chain at its top.
fn joint_name(rig: &Rig, j: usize) -> String {
    match rig.top_strands[j] {
        None => "tree".into(),
        Some(s) => format!("joint {j} (chain {s})"),
    }
}

/// The keys of a swapping node's weights: every sample time, plus one
/// just before the swap holding the old visibility; per key the motion
/// weights (linear between samples) then `hidden`.
pub(crate) fn swap_keys(
    times: &[f32],
    weights: &[f32],
    count: usize,
    swap: f32,
    hidden_before: bool,
    hidden_weight: f32,
) -> (Vec<f32>, Vec<f32>) {
    let hidden = |time: f32| {
        let before = time < swap;
        if before == hidden_before {
            hidden_weight
        } else {
            0.0
        }
    };
    let at = |k: usize| &weights[k * count..(k + 1) * count];
    let mut keys = Vec::with_capacity(times.len() + 1);
    let mut out = Vec::with_capacity((times.len() + 1) * (count + 1));
    for (k, &time) in times.iter().enumerate() {
        if k > 0 && times[k - 1] < swap && swap <= time {
            let edge = (swap - SWAP_EDGE).max(0.5 * (times[k - 1] + swap));
            let a = (edge - times[k - 1]) / (time - times[k - 1]);
            keys.push(edge);
            out.extend(at(k - 1).iter().zip(at(k)).map(|(x, y)| x + (y - x) * a));
            out.push(hidden(edge));
        }
        keys.push(time);
        out.extend_from_slice(at(k));
        out.push(hidden(time));
    }
    (keys, out)
}
