//! The stream header's data model: meshes, materials, textures, the grid.

use super::wire::MAX_GRID_COORDINATE;

/// Everything a client needs before the first frame: topology, materials,
/// textures and how positions are quantised.
///
/// The encoder takes one (with float base positions) and the decoder
/// returns one (with the base positions as the decoder reconstructs them,
/// i.e. snapped to the grid; [`Encoder::header`](super::Encoder::header)
/// returns the same snapped copy on the encoding side).
#[derive(Clone, Debug, PartialEq)]
pub struct StreamHeader {
    /// Axis-aligned bounds `[min, max]` of the whole animation, metres
    /// (Y up). Clients frame their camera with it before frames arrive;
    /// [`Grid::for_bounds`] derives the quantisation step from its height.
    /// Positions outside it are still encoded exactly as well.
    pub bounds: [[f32; 3]; 2],
    /// How positions are quantised.
    pub grid: Grid,
    /// Total number of frames, or 0 when unknown at the start of the
    /// stream (the end record always carries the actual count).
    pub frame_count: u32,
    /// Textures referenced by [`Material::texture`].
    pub textures: Vec<Texture>,
    /// Materials referenced by [`MaterialGroup`]s.
    pub materials: Vec<Material>,
    /// The meshes every frame carries positions for, in order (treemorph
    /// sends `branches` then `leaves`).
    pub meshes: Vec<Mesh>,
}

impl StreamHeader {
    /// Total number of vertices over all meshes.
    pub fn vertex_count(&self) -> usize {
        self.meshes.iter().map(|m| m.base_positions.len()).sum()
    }

    /// Checks every cross-reference and number; the reason on failure.
    pub(crate) fn check(&self) -> Result<(), String> {
        let [min, max] = self.bounds;
        if !(0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] <= max[a]) {
            return Err(format!(
                "bounds {:?} are not finite and ordered",
                self.bounds
            ));
        }
        self.grid.check()?;
        for (i, texture) in self.textures.iter().enumerate() {
            if !texture.png.starts_with(&PNG_SIGNATURE) {
                return Err(format!("texture {i} is not a PNG"));
            }
        }
        for (i, material) in self.materials.iter().enumerate() {
            if !material.base_color.iter().all(|c| (0.0..=1.0).contains(c)) {
                return Err(format!("material {i}: base colour outside [0, 1]"));
            }
            if let AlphaMode::Mask { cutoff } = material.alpha_mode
                && !(0.0..=1.0).contains(&cutoff)
            {
                return Err(format!(
                    "material {i}: alpha cutoff {cutoff} outside [0, 1]"
                ));
            }
            if let Some(t) = material.texture
                && t as usize >= self.textures.len()
            {
                return Err(format!("material {i}: texture {t} does not exist"));
            }
        }
        for (m, mesh) in self.meshes.iter().enumerate() {
            mesh.check(self.materials.len())
                .map_err(|reason| format!("mesh {m} ({:?}): {reason}", mesh.name))?;
        }
        Ok(())
    }
}

/// The PNG file signature every texture starts with.
pub(crate) const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];

/// A uniform quantisation grid: a position `p` travels as integer
/// coordinates `q` with `p ≈ origin + q · step` on each axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// World position of grid coordinate (0, 0, 0), metres.
    pub origin: [f32; 3],
    /// Grid spacing per axis, metres (finite and positive).
    pub step: [f32; 3],
}

impl Grid {
    /// A grid for an animation within `bounds` whose Euclidean
    /// quantisation error is at most `max_error_fraction` of the tree
    /// height (the Y extent of `bounds`; the largest extent if that is 0,
    /// 1 m if the bounds are a point). treemorph uses 0.001 (0.1 %).
    ///
    /// The grid is centred on the bounds; its step is widened if needed so
    /// the bounds fit well inside the ±[`MAX_GRID_COORDINATE`] range.
    /// Non-finite bounds or a non-positive fraction fall back to a unit
    /// box and 0.1 %.
    pub fn for_bounds(bounds: [[f32; 3]; 2], max_error_fraction: f32) -> Grid {
        let [min, max] = bounds;
        let finite = (0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] <= max[a]);
        let (min, max) = if finite {
            (min, max)
        } else {
            ([0.0; 3], [0.0; 3])
        };
        let extent = |a: usize| f64::from(max[a]) - f64::from(min[a]);
        let largest = extent(0).max(extent(1)).max(extent(2));
        let height = if extent(1) > 0.0 {
            extent(1)
        } else if largest > 0.0 {
            largest
        } else {
            1.0
        };
        let fraction = if max_error_fraction > 0.0 && max_error_fraction.is_finite() {
            f64::from(max_error_fraction)
        } else {
            0.001
        };
        // Euclidean error of rounding each axis: step·√3/2. Keep a small
        // margin for the f32 rounding of the reconstruction.
        let mut step = fraction * height * 2.0 / 3f64.sqrt() * 0.999;
        // Keep the bounds within half of the coordinate range so positions
        // a little outside them still fit.
        step = step.max(largest / f64::from(MAX_GRID_COORDINATE));
        let centre = |a: usize| ((f64::from(min[a]) + f64::from(max[a])) * 0.5) as f32;
        Grid {
            origin: [centre(0), centre(1), centre(2)],
            step: [step as f32; 3],
        }
    }

    /// The largest Euclidean distance between a position and its grid
    /// point, metres: `|step|/2`. The `f32` arithmetic of the
    /// reconstruction adds at most two ulps of the coordinates' magnitude
    /// on top ([`Grid::for_bounds`] leaves a margin for that).
    pub fn max_error(&self) -> f32 {
        let [x, y, z] = self.step.map(f64::from);
        ((x * x + y * y + z * z).sqrt() * 0.5) as f32
    }

    /// Grid coordinates of `p`, or `None` when `p` is not finite or lies
    /// outside the ±[`MAX_GRID_COORDINATE`] range.
    pub fn quantise(&self, p: [f32; 3]) -> Option<[i32; 3]> {
        let q = self.quantiser();
        let c = [0, 1, 2].map(|a| q.coordinate(a, p[a]));
        c.iter()
            .all(|c| Quantiser::in_range(*c))
            .then(|| c.map(Quantiser::round))
    }

    pub(crate) fn quantiser(&self) -> Quantiser {
        Quantiser {
            origin: self.origin.map(f64::from),
            inverse_step: self.step.map(|s| 1.0 / f64::from(s)),
        }
    }

    /// The position of grid coordinates `q`, computed exactly as the
    /// format specifies: `origin + f32(q) · step` in `f32` arithmetic.
    #[inline]
    pub fn dequantise(&self, q: [i32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| self.origin[a] + q[a] as f32 * self.step[a])
    }

    fn check(&self) -> Result<(), String> {
        if !self.origin.iter().all(|o| o.is_finite()) {
            return Err(format!("grid origin {:?} is not finite", self.origin));
        }
        if !self.step.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(format!(
                "grid step {:?} is not finite and positive",
                self.step
            ));
        }
        Ok(())
    }
}

/// The grid's quantisation in a form the encoder's hot loop can
/// vectorise: multiply by the inverse step, round with the 1.5·2⁵² trick
/// (ties to even, no libm call, no float-to-int conversion), check the
/// range without branching.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Quantiser {
    origin: [f64; 3],
    inverse_step: [f64; 3],
}

impl Quantiser {
    const ROUND: f64 = 6_755_399_441_055_744.0;

    /// The unrounded grid coordinate of `v` on `axis`.
    #[inline(always)]
    pub(crate) fn coordinate(&self, axis: usize, v: f32) -> f64 {
        (f64::from(v) - self.origin[axis]) * self.inverse_step[axis]
    }

    /// Whether a coordinate is finite and within the grid's range.
    #[inline(always)]
    pub(crate) fn in_range(c: f64) -> bool {
        c.abs() <= f64::from(MAX_GRID_COORDINATE)
    }

    /// The nearest integer of an in-range coordinate: adding 1.5·2⁵²
    /// leaves it in the low mantissa bits (two's complement), so no
    /// float-to-int conversion with its NaN and saturation checks is
    /// needed. Garbage (but no panic) for out-of-range input.
    #[inline(always)]
    pub(crate) fn round(c: f64) -> i32 {
        (c + Self::ROUND).to_bits() as u32 as i32
    }
}

/// An image, as PNG bytes (leaf textures carry alpha).
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct Texture {
    /// The PNG file.
    pub png: Vec<u8>,
}

/// How a material's alpha is used, as in glTF.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha is ignored.
    #[default]
    Opaque,
    /// Fragments with alpha below `cutoff` are discarded (leaf cut-outs).
    Mask {
        /// Alpha threshold in [0, 1]; glTF's default is 0.5.
        cutoff: f32,
    },
    /// Alpha blending.
    Blend,
}

/// A surface material, a subset of glTF's metallic-roughness material.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name (e.g. `bark`, `leaf-maple`).
    pub name: String,
    /// Linear RGBA factor in [0, 1], multiplied with the texture.
    pub base_color: [f32; 4],
    /// How alpha is used.
    pub alpha_mode: AlphaMode,
    /// Whether back faces are drawn (leaf billboards are).
    pub double_sided: bool,
    /// Index into [`StreamHeader::textures`] of the base colour texture.
    pub texture: Option<u32>,
}

impl Default for Material {
    /// Opaque white, single-sided, untextured, unnamed.
    fn default() -> Self {
        Material {
            name: String::new(),
            base_color: [1.0; 4],
            alpha_mode: AlphaMode::Opaque,
            double_sided: false,
            texture: None,
        }
    }
}

/// A range of a mesh's index buffer drawn with one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaterialGroup {
    /// First index (a multiple of 3) into [`Mesh::indices`].
    pub first: u32,
    /// Number of indices (a multiple of 3).
    pub count: u32,
    /// The material (index into [`StreamHeader::materials`]) at leaf blend 0.
    pub material: u32,
    /// The material the group cross-fades to as the frame's leaf blend goes
    /// from 0 to 1 (`None`: the group keeps `material`).
    pub fade_to: Option<u32>,
}

/// One mesh of the union topology: constant indices and UVs, and the
/// positions its frames start from.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Mesh {
    /// Name (treemorph: `branches` or `leaves`, like the glTF meshes).
    pub name: String,
    /// Triangle list: three vertex indices per triangle,
    /// counter-clockwise front faces (glTF convention).
    pub indices: Vec<u32>,
    /// Texture coordinates per vertex (glTF convention: v = 0 is the
    /// image's top row).
    pub uvs: Vec<[f32; 2]>,
    /// Ranges of `indices` with their materials.
    pub groups: Vec<MaterialGroup>,
    /// Positions of the vertices before the first frame (the first frame's
    /// positions, usually), metres. Frame 0 is sent as a delta from these.
    pub base_positions: Vec<[f32; 3]>,
}

impl Mesh {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.base_positions.len()
    }

    fn check(&self, materials: usize) -> Result<(), String> {
        let n = self.base_positions.len();
        if n > u32::MAX as usize || self.indices.len() > u32::MAX as usize {
            return Err("more than 2^32 - 1 vertices or indices".into());
        }
        if self.uvs.len() != n {
            return Err(format!("{} UVs for {n} vertices", self.uvs.len()));
        }
        if let Some(i) = self
            .uvs
            .iter()
            .position(|uv| !uv.iter().all(|c| c.is_finite()))
        {
            return Err(format!("UV {i} is not finite"));
        }
        if !self.indices.len().is_multiple_of(3) {
            return Err(format!(
                "{} indices is not a whole number of triangles",
                self.indices.len()
            ));
        }
        if let Some(i) = self.indices.iter().position(|&i| i as usize >= n) {
            return Err(format!(
                "index {i} ({}) is out of range for {n} vertices",
                self.indices[i]
            ));
        }
        for (g, group) in self.groups.iter().enumerate() {
            let end = u64::from(group.first) + u64::from(group.count);
            if !group.first.is_multiple_of(3)
                || !group.count.is_multiple_of(3)
                || end > self.indices.len() as u64
            {
                return Err(format!(
                    "group {g} (indices {}..{end}) is not a whole-triangle range of the {} indices",
                    group.first,
                    self.indices.len()
                ));
            }
            for m in [Some(group.material), group.fade_to].into_iter().flatten() {
                if m as usize >= materials {
                    return Err(format!("group {g}: material {m} does not exist"));
                }
            }
        }
        Ok(())
    }
}
