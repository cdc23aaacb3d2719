use std::sync::Arc;

use thiserror::Error;

/// Why a texture was refused.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum TextureError {
    /// The bytes are not a PNG image the decoder can read.
    #[error("not a readable PNG image: {0}")]
    NotPng(String),
    /// The image has a zero dimension.
    #[error("the image is empty ({width}×{height})")]
    Empty {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// The image is larger than allowed.
    #[error("the image is {width}×{height} pixels; at most {limit} pixels per side are allowed")]
    TooLarge {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Largest side allowed.
        limit: u32,
    },
    /// The pixel buffer does not match the stated size.
    #[error("{len} bytes of pixels do not make a {width}×{height} RGBA image")]
    BadBuffer {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Bytes given.
        len: usize,
    },
}

/// A decoded image: 8-bit RGBA, rows top to bottom.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbaImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 4` bytes, row-major from the top row.
    pub pixels: Vec<u8>,
}

impl RgbaImage {
    /// Checks the buffer size.
    pub fn new(width: u32, height: u32, pixels: Vec<u8>) -> Result<RgbaImage, TextureError> {
        if width == 0 || height == 0 {
            return Err(TextureError::Empty { width, height });
        }
        if pixels.len() as u64 != u64::from(width) * u64::from(height) * 4 {
            return Err(TextureError::BadBuffer {
                width,
                height,
                len: pixels.len(),
            });
        }
        Ok(RgbaImage {
            width,
            height,
            pixels,
        })
    }

    /// The pixel at (x, y), y from the top.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = ((y * self.width + x) * 4) as usize;
        [
            self.pixels[i],
            self.pixels[i + 1],
            self.pixels[i + 2],
            self.pixels[i + 3],
        ]
    }
}

/// A PNG image kept as its encoded bytes, with its size read from the
/// header. Cloning is cheap (the bytes are shared).
///
/// Serialised as its PNG bytes; deserialising reads the header again with
/// [`Texture::from_png`], so a stored texture is checked as an uploaded one.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(into = "Vec<u8>", try_from = "Vec<u8>")]
pub struct Texture {
    png: Arc<[u8]>,
    width: u32,
    height: u32,
}

impl From<Texture> for Vec<u8> {
    fn from(texture: Texture) -> Vec<u8> {
        texture.png.to_vec()
    }
}

impl TryFrom<Vec<u8>> for Texture {
    type Error = TextureError;

    fn try_from(png: Vec<u8>) -> Result<Texture, TextureError> {
        Texture::from_png(png, DEFAULT_MAX_TEXTURE_SIDE)
    }
}

/// Textures larger than this per side are refused by default.
pub(crate) const DEFAULT_MAX_TEXTURE_SIDE: u32 = 4096;

impl Texture {
    /// Accepts PNG bytes after reading the header and checking the size.
    ///
    /// Only the header is read here (cheap and bounded); the pixels are
    /// decoded on demand by [`Texture::decode`], which checks them too.
    pub fn from_png(bytes: impl Into<Arc<[u8]>>, max_side: u32) -> Result<Texture, TextureError> {
        let png: Arc<[u8]> = bytes.into();
        let decoder = png::Decoder::new(std::io::Cursor::new(&png[..]));
        let reader = decoder
            .read_info()
            .map_err(|e| TextureError::NotPng(e.to_string()))?;
        let info = reader.info();
        let (width, height) = (info.width, info.height);
        if width == 0 || height == 0 {
            return Err(TextureError::Empty { width, height });
        }
        if width > max_side || height > max_side {
            return Err(TextureError::TooLarge {
                width,
                height,
                limit: max_side,
            });
        }
        Ok(Texture { png, width, height })
    }

    /// Encodes an RGBA image as PNG.
    pub fn from_rgba(image: &RgbaImage) -> Texture {
        let mut out = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut out, image.width, image.height);
            encoder.set_color(png::ColorType::Rgba);
            encoder.set_depth(png::BitDepth::Eight);
            encoder.set_compression(png::Compression::Fast);
            // Writing to a Vec cannot fail and the buffer size was checked by
            // `RgbaImage::new`.
            let mut writer = encoder
                .write_header()
                .expect("PNG header to a Vec cannot fail");
            writer
                .write_image_data(&image.pixels)
                .expect("pixel buffer size was checked by RgbaImage::new");
        }
        Texture {
            png: out.into(),
            width: image.width,
            height: image.height,
        }
    }

    /// The encoded PNG bytes.
    pub fn png(&self) -> &[u8] {
        &self.png
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Decodes to 8-bit RGBA (grey, RGB, palette and 16-bit images are
    /// expanded).
    pub fn decode(&self) -> Result<RgbaImage, TextureError> {
        let mut decoder = png::Decoder::new(std::io::Cursor::new(&self.png[..]));
        decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = decoder
            .read_info()
            .map_err(|e| TextureError::NotPng(e.to_string()))?;
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| TextureError::NotPng("image too large to decode".into()))?;
        let mut buf = vec![0; size];
        let frame = reader
            .next_frame(&mut buf)
            .map_err(|e| TextureError::NotPng(e.to_string()))?;
        buf.truncate(frame.buffer_size());
        let (w, h) = (frame.width, frame.height);
        let pixels = match frame.color_type {
            png::ColorType::Rgba => buf,
            png::ColorType::Rgb => buf
                .chunks_exact(3)
                .flat_map(|c| [c[0], c[1], c[2], 255])
                .collect(),
            png::ColorType::GrayscaleAlpha => buf
                .chunks_exact(2)
                .flat_map(|c| [c[0], c[0], c[0], c[1]])
                .collect(),
            png::ColorType::Grayscale => buf.iter().flat_map(|&g| [g, g, g, 255]).collect(),
            png::ColorType::Indexed => {
                return Err(TextureError::NotPng(
                    "indexed colour was not expanded".into(),
                ));
            }
        };
        RgbaImage::new(w, h, pixels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgba_round_trips_through_png() {
        let pixels: Vec<u8> = (0..4 * 3 * 4).map(|i| (i * 7 % 256) as u8).collect();
        let image = RgbaImage::new(4, 3, pixels).unwrap();
        let texture = Texture::from_rgba(&image);
        assert_eq!((texture.width(), texture.height()), (4, 3));
        let again = Texture::from_png(texture.png().to_vec(), 4096).unwrap();
        assert_eq!(again.decode().unwrap(), image);
    }

    #[test]
    fn refuses_garbage_and_oversized_images() {
        assert!(matches!(
            Texture::from_png(vec![1, 2, 3], 4096),
            Err(TextureError::NotPng(_))
        ));
        let image = RgbaImage::new(8, 2, vec![0; 64]).unwrap();
        let texture = Texture::from_rgba(&image);
        assert_eq!(
            Texture::from_png(texture.png().to_vec(), 4),
            Err(TextureError::TooLarge {
                width: 8,
                height: 2,
                limit: 4
            })
        );
    }

    #[test]
    fn refuses_bad_buffers() {
        assert_eq!(
            RgbaImage::new(2, 2, vec![0; 15]),
            Err(TextureError::BadBuffer {
                width: 2,
                height: 2,
                len: 15
            })
        );
        assert_eq!(
            RgbaImage::new(0, 2, vec![]),
            Err(TextureError::Empty {
                width: 0,
                height: 2
            })
        );
    }
}
