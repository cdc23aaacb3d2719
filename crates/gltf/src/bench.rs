//! A synthetic frame sequence and timing harness for the frame encoders,
//! for `treemorph bench` and this crate's timing tests.
//!
//! [`Sway`] turns a static tree into a frame sequence until the morph and
//! sketch pipelines provide real ones: every node and leaf anchor moves by
//! a smooth displacement field that grows with height (a tree swaying in
//! the wind), and every leaf fades from its material to the next one (the
//! generator's presets have two tints of one leaf shape), so the texture
//! blending paths are exercised too. [`run`] meshes and encodes it with
//! every encoder and reports sizes and times.

use std::f32::consts::TAU;
use std::io::Write;
use std::time::Instant;

use glam::{Quat, Vec3};
use treemorph_api::delta::{Decoder, DecoderOptions, Encoder, Event};
use treemorph_tree::{Aabb, Frame, FrameLeaf, FrameTopology, Tree};

use crate::animated::{
    AnimatedEncoding, AnimatedGlbBuilder, AnimatedOptions, KEYFRAMES_MESH, keyframe_indices,
};
use crate::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use crate::frames::{EncodeError, FrameMeshes};
use crate::mesh::MeshOptions;
use crate::stream::{DeltaStreamWriter, StreamOptions};

/// A swaying, leaf-fading frame sequence made from a static tree.
#[derive(Clone, Debug)]
pub struct Sway {
    topology: FrameTopology,
    rest: Frame,
    height: f32,
    frames: usize,
}

impl Sway {
    /// A sequence of `frames` frames (at least 1) of `tree` swaying once
    /// back and forth while its leaves fade to the next leaf material.
    pub fn new(tree: &Tree, frames: usize) -> Sway {
        let mut topology = FrameTopology::of_tree(tree);
        let materials = topology.leaf_materials.len() as u32;
        if materials > 1 {
            for leaf in &mut topology.leaves {
                leaf.materials[1] = (leaf.materials[0] + 1) % materials;
            }
        }
        let rest = Frame::of_tree(tree);
        let height = tree.stats().height.max(1e-3);
        Sway {
            topology,
            rest,
            height,
            frames: frames.max(1),
        }
    }

    /// The union topology (leaves fade from their material to the next).
    pub fn topology(&self) -> &FrameTopology {
        &self.topology
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames
    }

    /// Whether there are no frames (never).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Reference radii: the radii never change.
    pub fn reference_radii(&self) -> &[f32] {
        &self.rest.radii
    }

    /// Sway amplitude at the top, metres.
    fn amplitude(&self) -> f32 {
        0.04 * self.height
    }

    /// Bounds holding every frame's meshes: the rest frame's nodes grown
    /// by the sway amplitude and the largest radius or leaf.
    pub fn bounds(&self) -> Aabb {
        let reach = self
            .rest
            .leaves
            .iter()
            .map(|l| l.width.max(l.height))
            .chain(self.rest.radii.iter().map(|r| 2.0 * r))
            .fold(0.0f32, f32::max);
        Aabb::of_points(self.rest.positions.iter().copied())
            .union(Aabb::of_points(self.rest.leaves.iter().map(|l| l.anchor)))
            .inflated(self.amplitude() + reach)
    }

    fn displace(&self, p: Vec3, phase: f32) -> Vec3 {
        let h = (p.y / self.height).clamp(0.0, 1.0);
        let a = self.amplitude() * h * h;
        p + Vec3::new(
            a * (phase + 0.3 * p.x).sin(),
            -0.1 * a * (phase + 0.2 * p.z).sin().abs(),
            0.6 * a * (phase + 0.3 * p.z).cos(),
        )
    }

    /// Frame `i` (clamped to the last).
    pub fn frame(&self, i: usize) -> Frame {
        let mut frame = self.rest.clone();
        self.frame_into(i, &mut frame);
        frame
    }

    /// Frame `i` written into `frame` (whose buffers are reused).
    pub fn frame_into(&self, i: usize, frame: &mut Frame) {
        let t = if self.frames <= 1 {
            0.0
        } else {
            i.min(self.frames - 1) as f32 / (self.frames - 1) as f32
        };
        let phase = TAU * t;
        let blend = t * t * (3.0 - 2.0 * t);
        frame.t = t;
        frame.bark_blend = blend;
        frame.radii.clone_from(&self.rest.radii);
        frame.positions.clear();
        frame
            .positions
            .extend(self.rest.positions.iter().map(|&p| self.displace(p, phase)));
        frame.leaves.clear();
        frame.leaves.extend(self.rest.leaves.iter().map(|l| {
            let anchor = self.displace(l.anchor, phase);
            FrameLeaf {
                anchor,
                orientation: Quat::from_rotation_z(0.15 * (phase + anchor.x).sin()) * l.orientation,
                blend,
                ..*l
            }
        }));
    }
}

/// What [`run`] measures.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct BenchOptions {
    /// Frames of the sequence (default 60).
    pub frames: usize,
    /// Keyframes of the animated GLBs (default 60).
    pub keyframes: usize,
    /// Animated GLB encodings to build (default all three; building the
    /// float one at 20,000 chains and 60 keyframes takes gigabytes).
    pub animated: Vec<AnimatedEncoding>,
    /// Meshes of the per-frame GLB (default [`FrameGlbOptions::default`]).
    pub frame_glb: FrameGlbOptions,
    /// The delta stream (default [`StreamOptions::default`]).
    pub stream: StreamOptions,
    /// The animated GLB's meshes (default [`KEYFRAMES_MESH`]: the cases
    /// build one morph target per keyframe).
    pub animated_mesh: MeshOptions,
}

impl Default for BenchOptions {
    fn default() -> BenchOptions {
        BenchOptions {
            frames: 60,
            keyframes: 60,
            animated: vec![
                AnimatedEncoding::Float,
                AnimatedEncoding::Quantized,
                AnimatedEncoding::Meshopt,
            ],
            frame_glb: FrameGlbOptions::default(),
            stream: StreamOptions::default(),
            animated_mesh: KEYFRAMES_MESH,
        }
    }
}

/// Size and build time of one animated GLB.
#[derive(Clone, Debug, PartialEq)]
pub struct AnimatedFigure {
    /// The encoding.
    pub encoding: AnimatedEncoding,
    /// Keyframes.
    pub keyframes: usize,
    /// File size, bytes.
    pub bytes: u64,
    /// Meshing, encoding and writing the file (to a byte counter), ms.
    pub build_ms: f64,
}

/// Measured figures of one [`run`]. Times are medians over the frames
/// (fastest in brackets where given), so other processes on a shared
/// machine skew them less.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchReport {
    /// Strands (≈ chains) of the tree.
    pub strands: usize,
    /// Leaves of the tree.
    pub leaves: usize,
    /// Vertices of the `branches` and `leaves` meshes of the per-frame GLB.
    pub glb_vertices: [usize; 2],
    /// Meshing one frame with the per-frame GLB's meshers (branches and
    /// leaves in parallel), ms: median and fastest.
    pub mesh_ms: [f64; 2],
    /// Meshing with quad leaves, ms: median and fastest.
    pub mesh_quads_ms: [f64; 2],
    /// Mean per-frame GLB size, bytes.
    pub frame_glb_bytes: f64,
    /// Writing one per-frame GLB (meshing included), ms: median and fastest.
    pub frame_glb_ms: [f64; 2],
    /// Vertices of the delta stream's meshes.
    pub delta_vertices: usize,
    /// Preamble and header record, bytes.
    pub delta_header_bytes: usize,
    /// Mean frame record size, bytes.
    pub delta_bytes_per_frame: f64,
    /// Encoding one frame record (the codec alone), ms: median and fastest.
    pub delta_encode_ms: [f64; 2],
    /// Meshing and encoding one frame, ms: median and fastest.
    pub delta_frame_ms: [f64; 2],
    /// Largest decoded position error, as a fraction of the bounds' height.
    pub delta_max_error_fraction: f64,
    /// The animated GLBs.
    pub animated: Vec<AnimatedFigure>,
}

impl BenchReport {
    /// Delta bytes per frame over per-frame GLB bytes.
    pub fn delta_ratio(&self) -> f64 {
        self.delta_bytes_per_frame / self.frame_glb_bytes
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

fn fastest(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

fn ms(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

/// One timed step of [`run`], applied to every frame.
type Step<'a> = dyn FnMut(&Frame) -> Result<(), EncodeError> + 'a;

/// Counts bytes written.
struct Counter(u64);

impl Write for Counter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0 += buf.len() as u64;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Encodes a [`Sway`] of `tree` with every encoder and measures it.
///
/// Errors: whatever the encoders return (a bug, since the input is valid).
pub fn run(tree: &Tree, options: &BenchOptions) -> Result<BenchReport, EncodeError> {
    let sway = Sway::new(tree, options.frames);
    let topology = sway.topology();
    let radii = sway.reference_radii();
    let frames: Vec<Frame> = (0..sway.len()).map(|i| sway.frame(i)).collect();
    let timed = |mut f: Box<Step<'_>>| {
        let mut times = Vec::with_capacity(frames.len());
        for frame in &frames {
            let start = Instant::now();
            f(frame)?;
            times.push(ms(start));
        }
        Ok::<_, EncodeError>([median(&mut times.clone()), fastest(&times)])
    };

    // Meshing.
    let mut meshes = FrameMeshes::new(topology, radii, &options.frame_glb.mesh)?;
    let mesh_ms = timed(Box::new(|f| meshes.mesh(f).map(|_| ())))?;
    let glb_vertices = [
        meshes.branches().vertex_count(),
        meshes.leaves().vertex_count(),
    ];
    let mut quads = FrameMeshes::new(topology, radii, &MeshOptions::default())?;
    let mesh_quads_ms = timed(Box::new(|f| quads.mesh(f).map(|_| ())))?;

    // Per-frame GLBs (the blended textures are cached after the first
    // frames, as in a real sequence).
    let mut writer = FrameGlbWriter::new(topology, radii, &options.frame_glb)?;
    let mut glb = Vec::new();
    let mut glb_bytes = 0usize;
    let frame_glb_ms = timed(Box::new(|f| {
        writer.write_into(f, &mut glb)?;
        glb_bytes += glb.len();
        Ok(())
    }))?;

    // The delta stream.
    let bounds = sway.bounds();
    let mut stream = DeltaStreamWriter::new(topology, radii, bounds, &options.stream)?;
    let mut bytes = Vec::new();
    let mut record = Vec::new();
    let mut header_bytes = 0;
    let mut frame_bytes = 0usize;
    let delta_frame_ms = timed(Box::new(|f| {
        record.clear();
        stream.write_frame(f, &mut record)?;
        if header_bytes == 0 {
            header_bytes = record.len();
        } else {
            frame_bytes += record.len();
        }
        bytes.extend_from_slice(&record);
        Ok(())
    }))?;
    stream.finish(&mut bytes)?;
    // The first record carries the header too.
    let header_only = header_bytes.saturating_sub(
        frame_bytes
            .checked_div(frames.len().saturating_sub(1))
            .unwrap_or(0),
    );
    let delta_vertices = stream.header().map_or(0, |h| h.vertex_count());
    let height = f64::from(bounds.size().y);
    // The codec alone: the same frames re-encoded from meshes made
    // beforehand, and the decoded positions checked against them.
    let mut encode = Vec::with_capacity(frames.len());
    let mut max_error = 0f64;
    if let Some(header) = stream.header() {
        let mut encoder = Encoder::new(header.clone(), &options.stream.encoder)?;
        let mut decoder = Decoder::new(&DecoderOptions::default());
        decoder.push(encoder.header_bytes());
        let mut meshes = FrameMeshes::new(topology, radii, &options.stream.mesh)?;
        for (i, f) in frames.iter().enumerate() {
            let (b, l) = meshes.mesh(f)?;
            record.clear();
            let start = Instant::now();
            encoder.encode_frame_of(
                i as u32,
                f.t,
                &[&b.positions, &l.positions],
                0.0,
                &mut record,
            )?;
            encode.push(ms(start));
            decoder.push(&record);
            while let Some(event) = decoder.next_event()? {
                if let Event::Frame(frame) = event {
                    for (decoded, mesh) in frame.positions.iter().zip([b, l]) {
                        for (d, p) in decoded.iter().zip(&mesh.positions) {
                            let e = (Vec3::from_array(*d) - *p).length();
                            max_error = max_error.max(f64::from(e));
                        }
                    }
                }
            }
        }
    }

    // Animated GLBs.
    let picks = keyframe_indices(frames.len(), options.keyframes);
    let mut animated = Vec::new();
    for &encoding in &options.animated {
        let start = Instant::now();
        let anim_options = AnimatedOptions::default()
            .with_encoding(encoding)
            .with_keyframes(options.keyframes)
            .with_mesh(options.animated_mesh.clone());
        let mut builder = AnimatedGlbBuilder::new(topology, radii, bounds, &anim_options)?;
        for &i in &picks {
            builder.push(&frames[i])?;
        }
        let bytes = builder.finish_to(&mut Counter(0))?;
        animated.push(AnimatedFigure {
            encoding,
            keyframes: picks.len(),
            bytes,
            build_ms: ms(start),
        });
    }

    let n = frames.len().max(1) as f64;
    Ok(BenchReport {
        strands: topology.strands.len(),
        leaves: topology.leaves.len(),
        glb_vertices,
        mesh_ms,
        mesh_quads_ms,
        frame_glb_bytes: glb_bytes as f64 / n,
        frame_glb_ms,
        delta_vertices,
        delta_header_bytes: header_only,
        delta_bytes_per_frame: frame_bytes as f64 / (n - 1.0).max(1.0),
        delta_encode_ms: [median(&mut encode.clone()), fastest(&encode)],
        delta_frame_ms,
        delta_max_error_fraction: max_error / height,
        animated,
    })
}
