//! The GLB container (glTF 2.0 binary, §4.4 of the specification).
//!
//! A GLB is a 12-byte header (`"glTF"`, version 2, total length) followed by
//! chunks of `length, type, data`: first the JSON chunk (padded with spaces
//! to a multiple of 4 bytes), then optionally one BIN chunk (padded with
//! zeros). All numbers are little-endian `u32`. Reading checks every length
//! against the bytes actually present before slicing, so hostile input gives
//! a [`GlbError`] and never a panic or an allocation sized by a declared
//! length.

use thiserror::Error;

/// `"glTF"` read as a little-endian `u32`.
pub const MAGIC: u32 = 0x4654_6C67;
/// Chunk type of the JSON chunk (`"JSON"`).
pub const CHUNK_JSON: u32 = 0x4E4F_534A;
/// Chunk type of the binary chunk (`"BIN\0"`).
pub const CHUNK_BIN: u32 = 0x004E_4942;
const HEADER_LEN: usize = 12;
const CHUNK_HEADER_LEN: usize = 8;

/// Why bytes are not a GLB container this crate can read or write.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum GlbError {
    /// The bytes do not start with the GLB magic `glTF`.
    #[error("not a GLB file (the first four bytes are not \"glTF\")")]
    NotGlb,
    /// The container version is not 2.
    #[error("GLB container version {0} is not supported; only version 2 is")]
    UnsupportedVersion(u32),
    /// A length or chunk layout is inconsistent with the bytes present.
    #[error("malformed GLB: {0}")]
    Malformed(String),
    /// The file would exceed the 4 GiB a GLB header can describe.
    #[error("a GLB holds at most 4 GiB; this one would be {0} bytes")]
    TooLarge(u64),
}

/// A GLB container split into its chunks (borrowed from the input).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Glb<'a> {
    /// The JSON chunk's data (may end in padding spaces).
    pub json: &'a [u8],
    /// The BIN chunk's data, when there is one (may end in padding zeros).
    pub bin: Option<&'a [u8]>,
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

impl<'a> Glb<'a> {
    /// Splits a GLB into its chunks. Bytes after the header's declared
    /// length are ignored; chunks of unknown type after the JSON chunk are
    /// skipped, as the specification asks.
    pub fn from_slice(bytes: &'a [u8]) -> Result<Glb<'a>, GlbError> {
        if bytes.len() < 4 || u32_at(bytes, 0) != Some(MAGIC) {
            return Err(GlbError::NotGlb);
        }
        let (Some(version), Some(length)) = (u32_at(bytes, 4), u32_at(bytes, 8)) else {
            return Err(GlbError::Malformed(format!(
                "{} bytes are too few for the 12-byte header",
                bytes.len()
            )));
        };
        if version != 2 {
            return Err(GlbError::UnsupportedVersion(version));
        }
        let length = length as usize;
        if length > bytes.len() {
            return Err(GlbError::Malformed(format!(
                "the header declares {length} bytes but only {} are present",
                bytes.len()
            )));
        }
        let bytes = &bytes[..length];
        let mut at = HEADER_LEN;
        let mut json = None;
        let mut bin = None;
        let mut index = 0;
        while at < bytes.len() {
            let (Some(len), Some(kind)) = (u32_at(bytes, at), u32_at(bytes, at + 4)) else {
                return Err(GlbError::Malformed(format!(
                    "chunk {index} at byte {at} has a truncated header"
                )));
            };
            let start = at + CHUNK_HEADER_LEN;
            let data = start
                .checked_add(len as usize)
                .and_then(|end| bytes.get(start..end))
                .ok_or_else(|| {
                    GlbError::Malformed(format!(
                        "chunk {index} declares {len} bytes but only {} remain",
                        bytes.len() - start.min(bytes.len())
                    ))
                })?;
            match (index, kind) {
                (0, CHUNK_JSON) => json = Some(data),
                (0, _) => {
                    return Err(GlbError::Malformed(format!(
                        "the first chunk has type {kind:#010x}, not JSON"
                    )));
                }
                (1, CHUNK_BIN) => bin = Some(data),
                (_, CHUNK_JSON) | (_, CHUNK_BIN) => {
                    return Err(GlbError::Malformed(format!(
                        "chunk {index} repeats or misplaces a JSON or BIN chunk"
                    )));
                }
                _ => {}
            }
            at = start + data.len();
            index += 1;
        }
        let json = json.ok_or_else(|| GlbError::Malformed("there is no JSON chunk".into()))?;
        Ok(Glb { json, bin })
    }

    /// Writes the container: the JSON chunk padded with spaces and the BIN
    /// chunk (omitted when `bin` is `None`) padded with zeros.
    pub fn to_vec(&self) -> Result<Vec<u8>, GlbError> {
        match self.bin {
            Some(bin) => write_with(self.json, Some(bin.len()), |out| out.copy_from_slice(bin)),
            None => write_with(self.json, None, |_| {}),
        }
    }
}

/// Writes a GLB whose BIN chunk of `bin_len` bytes (none when `None`) is
/// filled in place by `fill`, so large binary data is written once, straight
/// into the file, instead of being built apart and copied.
pub fn write_with(
    json: &[u8],
    bin_len: Option<usize>,
    fill: impl FnOnce(&mut [u8]),
) -> Result<Vec<u8>, GlbError> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad(json.len());
    let bin_padded = bin_len.map(|n| n + pad(n));
    let total = HEADER_LEN as u64
        + (CHUNK_HEADER_LEN + json_len) as u64
        + bin_padded.map_or(0, |n| (CHUNK_HEADER_LEN + n) as u64);
    let total32 = u32::try_from(total).map_err(|_| GlbError::TooLarge(total))?;
    // Zeroed memory comes straight from the allocator; only the parts
    // written below are touched once.
    let mut out = vec![0u8; total as usize];
    let mut at = 0;
    let mut put = |bytes: &[u8]| {
        out[at..at + bytes.len()].copy_from_slice(bytes);
        at += bytes.len();
    };
    put(&MAGIC.to_le_bytes());
    put(&2u32.to_le_bytes());
    put(&total32.to_le_bytes());
    put(&(json_len as u32).to_le_bytes());
    put(&CHUNK_JSON.to_le_bytes());
    put(json);
    put(&b"   "[..pad(json.len())]);
    if let (Some(len), Some(padded)) = (bin_len, bin_padded) {
        put(&(padded as u32).to_le_bytes());
        put(&CHUNK_BIN.to_le_bytes());
        fill(&mut out[at..at + len]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_padded_chunks_and_reads_them_back() {
        let glb = Glb {
            json: b"{\"a\":1}",
            bin: Some(&[1, 2, 3, 4, 5]),
        };
        let bytes = glb.to_vec().unwrap();
        assert_eq!(bytes.len(), 12 + 8 + 8 + 8 + 8);
        assert_eq!(&bytes[..4], b"glTF");
        assert_eq!(u32_at(&bytes, 8), Some(bytes.len() as u32));
        let back = Glb::from_slice(&bytes).unwrap();
        assert_eq!(back.json, b"{\"a\":1} ");
        assert_eq!(back.bin, Some(&[1u8, 2, 3, 4, 5, 0, 0, 0][..]));
    }

    #[test]
    fn omits_an_absent_bin_chunk() {
        let bytes = Glb {
            json: b"{}",
            bin: None,
        }
        .to_vec()
        .unwrap();
        assert_eq!(bytes.len(), 12 + 8 + 4);
        assert_eq!(Glb::from_slice(&bytes).unwrap().bin, None);
    }

    #[test]
    fn refuses_bad_headers_and_chunks() {
        let good = Glb {
            json: b"{}",
            bin: Some(b"abcd"),
        }
        .to_vec()
        .unwrap();
        assert_eq!(Glb::from_slice(b"glT"), Err(GlbError::NotGlb));
        assert_eq!(Glb::from_slice(b"GLTF\x02\0\0\0"), Err(GlbError::NotGlb));
        assert!(matches!(
            Glb::from_slice(b"glTF\x02\0\0"),
            Err(GlbError::Malformed(_))
        ));
        let mut v1 = good.clone();
        v1[4] = 1;
        assert_eq!(Glb::from_slice(&v1), Err(GlbError::UnsupportedVersion(1)));
        let mut long = good.clone();
        long[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            Glb::from_slice(&long),
            Err(GlbError::Malformed(_))
        ));
        let mut chunk = good.clone();
        chunk[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            Glb::from_slice(&chunk),
            Err(GlbError::Malformed(_))
        ));
        let mut bin_first = good.clone();
        bin_first[16..20].copy_from_slice(&CHUNK_BIN.to_le_bytes());
        assert!(matches!(
            Glb::from_slice(&bin_first),
            Err(GlbError::Malformed(_))
        ));
        // Truncated anywhere: an error, never a panic.
        for n in 0..good.len() {
            assert!(Glb::from_slice(&good[..n]).is_err(), "prefix of {n} bytes");
        }
    }
}
