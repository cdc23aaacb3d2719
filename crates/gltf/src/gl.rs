//! The numeric enums of glTF 2.0 (OpenGL's values): accessor component
//! types, buffer view targets, primitive modes and sampler settings.
//!
//! One named set for the encoders here and the importer, so that no file
//! spells `5126` for `FLOAT`.

/// `componentType`: signed 8-bit.
pub const BYTE: u32 = 5120;
/// `componentType`: unsigned 8-bit.
pub const UNSIGNED_BYTE: u32 = 5121;
/// `componentType`: signed 16-bit.
pub const SHORT: u32 = 5122;
/// `componentType`: unsigned 16-bit.
pub const UNSIGNED_SHORT: u32 = 5123;
/// `componentType`: unsigned 32-bit (indices only).
pub const UNSIGNED_INT: u32 = 5125;
/// `componentType`: 32-bit float.
pub const FLOAT: u32 = 5126;

/// Buffer view `target`: vertex attributes.
pub const ARRAY_BUFFER: u32 = 34962;
/// Buffer view `target`: indices.
pub const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Primitive `mode`: separate triangles (the default).
pub const TRIANGLES: u32 = 4;
/// Primitive `mode`: a triangle strip.
pub const TRIANGLE_STRIP: u32 = 5;
/// Primitive `mode`: a triangle fan (the last mode glTF defines).
pub const TRIANGLE_FAN: u32 = 6;

/// Sampler `magFilter` / `minFilter`: linear.
pub const LINEAR: u32 = 9729;
/// Sampler `minFilter`: trilinear (linear within and between mipmaps).
pub const LINEAR_MIPMAP_LINEAR: u32 = 9987;
/// Sampler `wrapS` / `wrapT`: repeat.
pub const REPEAT: u32 = 10497;
/// Sampler `wrapS` / `wrapT`: clamp to the edge.
pub const CLAMP_TO_EDGE: u32 = 33071;
