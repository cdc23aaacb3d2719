//! A synthetic workload and timing harness for the delta codec, for
//! `treemorph bench` and the codec's own tests.
//!
//! [`Synthetic`] builds a tree-like pair of meshes: `branches` (tubes of
//! 8-vertex rings along straight chains) and `leaves` (quads at chain
//! tips, cross-fading between two leaf materials), scattered
//! deterministically through a 10 m tall crown. Its animation is a smooth
//! sway: every vertex moves by a displacement field that grows with height
//! and varies slowly in space and time, so neighbouring vertices move
//! alike, as in a morph.

use std::time::Instant;

use super::types::{AlphaMode, Grid, Material, MaterialGroup, Mesh, StreamHeader, Texture};
use super::{DecoderOptions, DeltaError, Encoder, EncoderOptions, Event};

/// Vertices per tube ring.
const RING: usize = 8;
/// Rings per chain.
const RINGS: usize = 6;
/// Leaves per chain.
const LEAVES: usize = 3;
/// Vertices per synthetic chain: its tube and its leaves.
pub const VERTICES_PER_CHAIN: usize = RING * RINGS + 4 * LEAVES;
/// Crown height, metres.
const HEIGHT: f32 = 10.0;
/// Sway amplitude at the top, metres.
const SWAY: f32 = 0.5;

/// A 1×1 RGBA PNG (a translucent green pixel), standing in for a leaf
/// texture.
pub const TINY_PNG: [u8; 70] = [
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x06, 0x00, 0x00, 0x00, 0x1f, 0x15, 0xc4,
    0x89, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0x08, 0x58, 0x60, 0x70,
    0x00, 0x00, 0x04, 0x45, 0x01, 0xe1, 0x0c, 0x46, 0x24, 0x7e, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45,
    0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
];

/// A deterministic synthetic tree animation of a chosen size.
#[derive(Clone, Debug)]
pub struct Synthetic {
    header: StreamHeader,
    /// Per mesh: base positions.
    base: Vec<Vec<[f32; 3]>>,
}

fn hash(seed: u64) -> u64 {
    // splitmix64
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn unit(seed: u64) -> f32 {
    (hash(seed) >> 40) as f32 / (1u64 << 24) as f32
}

impl Synthetic {
    /// An animation of `chains` chains: `chains ×` [`VERTICES_PER_CHAIN`]
    /// (60) vertices, 48 in the chain's tube and 12 in its three leaves.
    pub fn new(chains: usize, frame_count: u32) -> Synthetic {
        let mut branches = Mesh {
            name: "branches".into(),
            ..Mesh::default()
        };
        let mut leaves = Mesh {
            name: "leaves".into(),
            ..Mesh::default()
        };
        for c in 0..chains as u64 {
            let s = c * 16;
            let start = [
                (unit(s) - 0.5) * 6.0,
                1.0 + unit(s + 1) * (HEIGHT - 3.0),
                (unit(s + 2) - 0.5) * 6.0,
            ];
            let dir = [unit(s + 3) - 0.5, 0.3 + unit(s + 4), unit(s + 5) - 0.5];
            let len = 0.3 + unit(s + 6);
            let norm = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
            let d = dir.map(|v| v / norm * len);
            // An orthonormal-ish frame around the axis.
            let u = normalize([d[1], -d[0], 0.0]);
            let w = normalize(cross(d, u));
            let radius = 0.01 + 0.03 * unit(s + 7);
            let first = branches.base_positions.len() as u32;
            for r in 0..RINGS {
                let f = r as f32 / (RINGS - 1) as f32;
                let rad = radius * (1.0 - 0.7 * f);
                for k in 0..RING {
                    let a = k as f32 / RING as f32 * std::f32::consts::TAU;
                    let (sin, cos) = a.sin_cos();
                    branches.base_positions.push(
                        [0, 1, 2].map(|i| start[i] + d[i] * f + rad * (cos * u[i] + sin * w[i])),
                    );
                    branches.uvs.push([k as f32 / RING as f32, f]);
                }
            }
            for r in 0..RINGS as u32 - 1 {
                for k in 0..RING as u32 {
                    let a = first + r * RING as u32 + k;
                    let b = first + r * RING as u32 + (k + 1) % RING as u32;
                    let (a2, b2) = (a + RING as u32, b + RING as u32);
                    branches.indices.extend([a, b, a2, b, b2, a2]);
                }
            }
            let tip = [0, 1, 2].map(|i| start[i] + d[i]);
            for l in 0..LEAVES as u64 {
                let first = leaves.base_positions.len() as u32;
                let angle = unit(s + 8 + l) * std::f32::consts::TAU;
                let (sin, cos) = angle.sin_cos();
                let (size_w, size_h) = (0.08, 0.12);
                let base = [tip[0] + 0.02 * cos, tip[1], tip[2] + 0.02 * sin];
                let side = [-sin * size_w * 0.5, 0.0, cos * size_w * 0.5];
                let up = [cos * size_h * 0.5, size_h, sin * size_h * 0.5];
                for (corner, uv) in [
                    ([-1.0, 0.0], [0.0, 1.0]),
                    ([1.0, 0.0], [1.0, 1.0]),
                    ([1.0, 1.0], [1.0, 0.0]),
                    ([-1.0, 1.0], [0.0, 0.0]),
                ] {
                    leaves
                        .base_positions
                        .push([0, 1, 2].map(|i| base[i] + corner[0] * side[i] + corner[1] * up[i]));
                    leaves.uvs.push(uv);
                }
                leaves
                    .indices
                    .extend([first, first + 1, first + 2, first, first + 2, first + 3]);
            }
        }
        branches.groups.push(MaterialGroup {
            first: 0,
            count: branches.indices.len() as u32,
            material: 0,
            fade_to: None,
        });
        leaves.groups.push(MaterialGroup {
            first: 0,
            count: leaves.indices.len() as u32,
            material: 1,
            fade_to: Some(2),
        });
        let base = vec![
            branches.base_positions.clone(),
            leaves.base_positions.clone(),
        ];
        let bounds = [
            [-3.0 - SWAY - 1.5, 0.0, -3.0 - SWAY - 1.5],
            [3.0 + SWAY + 1.5, HEIGHT + 0.5, 3.0 + SWAY + 1.5],
        ];
        let leaf = |name: &str, color: [f32; 4]| Material {
            name: name.into(),
            base_color: color,
            alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
            double_sided: true,
            texture: Some(0),
        };
        let header = StreamHeader {
            bounds,
            grid: Grid::for_bounds(bounds, 0.001),
            frame_count,
            textures: vec![Texture {
                png: TINY_PNG.to_vec(),
            }],
            materials: vec![
                Material {
                    name: "bark".into(),
                    base_color: [0.35, 0.25, 0.18, 1.0],
                    ..Material::default()
                },
                leaf("leaf-spring", [0.4, 0.8, 0.3, 1.0]),
                leaf("leaf-autumn", [0.9, 0.5, 0.1, 1.0]),
            ],
            meshes: vec![branches, leaves],
        };
        Synthetic { header, base }
    }

    /// The stream header (float base positions, before snapping).
    pub fn header(&self) -> &StreamHeader {
        &self.header
    }

    /// Total vertex count.
    pub fn vertex_count(&self) -> usize {
        self.header.vertex_count()
    }

    /// Positions at animation time `t` into `out` (one `Vec` per mesh,
    /// reused).
    pub fn positions(&self, t: f32, out: &mut Vec<Vec<[f32; 3]>>) {
        out.resize(self.base.len(), Vec::new());
        for (base, out) in self.base.iter().zip(out.iter_mut()) {
            out.clear();
            out.extend(base.iter().map(|&[x, y, z]| {
                let h = (y / HEIGHT).clamp(0.0, 1.0);
                let a = SWAY * h * h;
                let phase = std::f32::consts::TAU * t;
                [
                    x + a * (phase + 0.3 * x).sin(),
                    y - 0.1 * a * (phase + 0.2 * z).sin().abs(),
                    z + 0.6 * a * (phase + 0.3 * z).cos(),
                ]
            }));
        }
    }

    /// Size of one frame as a standalone GLB without its textures: float
    /// positions, normals and UVs per vertex and 32-bit indices (plus
    /// ~2 KiB of JSON and chunk headers). Textures would add to every GLB
    /// but only once to the stream, so leaving them out flatters the GLB.
    pub fn glb_bytes_per_frame(&self) -> usize {
        let vertices = self.vertex_count();
        let indices: usize = self.header.meshes.iter().map(|m| m.indices.len()).sum();
        vertices * (12 + 12 + 8) + indices * 4 + 2048
    }
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 {
        v.map(|c| c / n)
    } else {
        [1.0, 0.0, 0.0]
    }
}

/// Measured figures of one [`run`].
#[derive(Clone, Debug, PartialEq)]
pub struct BenchReport {
    /// Vertices per frame.
    pub vertices: usize,
    /// Frames encoded.
    pub frames: u32,
    /// Preamble and header record, bytes.
    pub header_bytes: usize,
    /// Mean frame record size, bytes.
    pub bytes_per_frame: f64,
    /// One frame as a GLB without textures ([`Synthetic::glb_bytes_per_frame`]).
    pub glb_bytes_per_frame: usize,
    /// Median encode time per frame, milliseconds (the median, not the
    /// mean, so other processes on a shared machine skew it less).
    pub encode_ms_per_frame: f64,
    /// Median decode time per frame (decompression, reconstruction and
    /// dequantisation), milliseconds.
    pub decode_ms_per_frame: f64,
    /// Fastest frame encode, milliseconds (closest to an idle machine).
    pub encode_ms_min: f64,
    /// Fastest frame decode, milliseconds.
    pub decode_ms_min: f64,
    /// Largest distance between an input and a decoded position, as a
    /// fraction of the tree height.
    pub max_error_fraction: f64,
}

impl BenchReport {
    /// `bytes_per_frame / glb_bytes_per_frame`.
    pub fn ratio(&self) -> f64 {
        self.bytes_per_frame / self.glb_bytes_per_frame as f64
    }
}

/// Encodes and decodes `frames` frames of a [`Synthetic`] animation with
/// `chains` chains (60 vertices each), timing both sides and checking the
/// error against the input.
///
/// Errors: whatever the codec returns (a bug, since the input is valid).
pub fn run(
    chains: usize,
    frames: u32,
    options: &EncoderOptions,
) -> Result<BenchReport, DeltaError> {
    let synthetic = Synthetic::new(chains, frames);
    let [min, max] = synthetic.header.bounds;
    let height = max[1] - min[1];
    let mut inputs = Vec::with_capacity(frames as usize);
    let mut scratch = Vec::new();
    for i in 0..frames {
        synthetic.positions(time(i, frames), &mut scratch);
        inputs.push(scratch.clone());
    }
    let mut encoder = Encoder::new(synthetic.header.clone(), options)?;
    let header_bytes = encoder.header_bytes().len();
    let mut stream = encoder.header_bytes().to_vec();
    let mut record = Vec::new();
    let mut encode = Vec::with_capacity(frames as usize);
    let mut frame_bytes = 0usize;
    for (i, input) in inputs.iter().enumerate() {
        let slices: Vec<&[[f32; 3]]> = input.iter().map(Vec::as_slice).collect();
        record.clear();
        let started = Instant::now();
        encoder.encode_frame(i as u32, time(i as u32, frames), &slices, 0.0, &mut record)?;
        encode.push(started.elapsed().as_secs_f64());
        frame_bytes += record.len();
        stream.extend_from_slice(&record);
    }
    encoder.finish(&mut stream)?;

    let mut decoder = super::Decoder::new(&DecoderOptions::default());
    decoder.push(&stream);
    let mut decode = Vec::with_capacity(frames as usize);
    let mut max_error = 0f64;
    let mut decoded = 0usize;
    loop {
        let started = Instant::now();
        let event = decoder.next_event()?;
        let elapsed = started.elapsed().as_secs_f64();
        match event {
            Some(Event::Frame(frame)) => {
                decode.push(elapsed);
                let input = &inputs[decoded];
                for (got, want) in frame.positions.iter().zip(input) {
                    for (g, w) in got.iter().zip(want) {
                        let e = (0..3)
                            .map(|a| (f64::from(g[a]) - f64::from(w[a])).powi(2))
                            .sum::<f64>()
                            .sqrt();
                        max_error = max_error.max(e);
                    }
                }
                decoded += 1;
            }
            Some(_) => {}
            None => break,
        }
    }
    decoder.finish()?;
    let n = f64::from(frames.max(1));
    Ok(BenchReport {
        vertices: synthetic.vertex_count(),
        frames,
        header_bytes,
        bytes_per_frame: frame_bytes as f64 / n,
        glb_bytes_per_frame: synthetic.glb_bytes_per_frame(),
        encode_ms_per_frame: median(&mut encode) * 1e3,
        decode_ms_per_frame: median(&mut decode) * 1e3,
        encode_ms_min: encode.first().copied().unwrap_or(0.0) * 1e3,
        decode_ms_min: decode.first().copied().unwrap_or(0.0) * 1e3,
        max_error_fraction: max_error / f64::from(height),
    })
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Animation time of frame `i` of `frames`.
pub fn time(i: u32, frames: u32) -> f32 {
    if frames <= 1 {
        0.0
    } else {
        i as f32 / (frames - 1) as f32
    }
}
