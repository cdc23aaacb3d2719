#![allow(clippy::type_complexity)]

use proptest::prelude::*;

use super::bench::{Synthetic, TINY_PNG, time};
use super::wire::{self, BLOCK, KIND_ANCILLARY, PREAMBLE_LEN, PREFIX_LEN};
use super::*;

fn slices(p: &[Vec<[f32; 3]>]) -> Vec<&[[f32; 3]]> {
    p.iter().map(Vec::as_slice).collect()
}

/// Encodes `frames` frames of a small synthetic animation; returns the
/// stream, the inputs and the encoder's reconstruction after each frame.
fn synthetic_stream(
    chains: usize,
    frames: u32,
    options: &EncoderOptions,
) -> (
    Vec<u8>,
    Vec<Vec<Vec<[f32; 3]>>>,
    Vec<Vec<Vec<[f32; 3]>>>,
    StreamHeader,
) {
    let s = Synthetic::new(chains, frames);
    let mut encoder = Encoder::new(s.header().clone(), options).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    let (mut inputs, mut tracked) = (Vec::new(), Vec::new());
    let mut p = Vec::new();
    for i in 0..frames {
        s.positions(time(i, frames), &mut p);
        encoder
            .encode_frame(
                i,
                time(i, frames),
                &slices(&p),
                i as f32 / frames as f32,
                &mut stream,
            )
            .unwrap();
        inputs.push(p.clone());
        tracked.push(encoder.reconstructed_positions());
    }
    encoder.finish(&mut stream).unwrap();
    (stream, inputs, tracked, encoder.header().clone())
}

fn events(stream: &[u8], chunks: &[usize]) -> Result<Vec<Event>, DeltaError> {
    let mut decoder = Decoder::new(&DecoderOptions::default());
    let mut out = Vec::new();
    let mut at = 0;
    let mut sizes = chunks.iter().cycle();
    while at < stream.len() {
        let n = (*sizes.next().unwrap_or(&stream.len())).clamp(1, stream.len() - at);
        decoder.push(&stream[at..at + n]);
        at += n;
        while let Some(e) = decoder.next_event()? {
            out.push(e);
        }
    }
    while let Some(e) = decoder.next_event()? {
        out.push(e);
    }
    decoder.finish()?;
    Ok(out)
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f64 {
    (0..3)
        .map(|i| (f64::from(a[i]) - f64::from(b[i])).powi(2))
        .sum::<f64>()
        .sqrt()
}

fn height(header: &StreamHeader) -> f64 {
    f64::from(header.bounds[1][1] - header.bounds[0][1])
}

#[test]
fn zigzag_round_trips_the_extremes() {
    for v in [0, 1, -1, 2, -2, i32::MAX, i32::MIN, 1 << 24, -(1 << 24)] {
        assert_eq!(wire::unzigzag(wire::zigzag(v)), v);
    }
    assert_eq!(wire::zigzag(-1), 1);
    assert_eq!(wire::zigzag(1), 2);
    assert_eq!(wire::zigzag(i32::MIN), u32::MAX);
}

#[test]
fn decoding_reproduces_the_encoders_tracked_state_exactly() {
    for compression in [Compression::None, Compression::Zstd { level: 1 }] {
        let (stream, inputs, tracked, header) =
            synthetic_stream(40, 12, &EncoderOptions::with_compression(compression));
        let (decoded_header, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
        assert_eq!(decoded_header, header);
        assert_eq!(frames.len(), 12);
        let bound = 0.001 * height(&header);
        for (i, frame) in frames.iter().enumerate() {
            assert_eq!(frame.index, i as u32);
            assert_eq!(frame.t, time(i as u32, 12));
            assert_eq!(frame.leaf_blend, i as f32 / 12.0);
            assert_eq!(frame.positions, tracked[i], "frame {i}");
            for (got, want) in frame
                .positions
                .iter()
                .flatten()
                .zip(inputs[i].iter().flatten())
            {
                assert!(
                    distance(*got, *want) <= bound,
                    "frame {i}: {got:?} vs {want:?}"
                );
            }
        }
    }
}

/// A restarted encoder writes, after the header, what a new encoder of
/// the same header writes, whatever it encoded before.
#[test]
fn a_restarted_encoder_writes_what_a_new_one_writes() {
    // A header that announces no frame count, so streams of any length end.
    let s = Synthetic::new(30, 0);
    let options = EncoderOptions::default();
    let encode = |encoder: &mut Encoder, frames: &[u32]| {
        let mut out = encoder.header_bytes().to_vec();
        let mut p = Vec::new();
        for (index, &i) in frames.iter().enumerate() {
            s.positions(time(i, 8), &mut p);
            let blend = i as f32 / 8.0;
            encoder
                .encode_frame(index as u32, time(i, 8), &slices(&p), blend, &mut out)
                .unwrap();
        }
        out
    };
    let mut reused = Encoder::new(s.header().clone(), &options).unwrap();
    let mut first = encode(&mut reused, &[7, 3, 5]);
    reused.finish(&mut first).unwrap();
    reused.restart();
    let mut again = encode(&mut reused, &[2, 6]);
    reused.finish(&mut again).unwrap();
    let mut new = Encoder::new(s.header().clone(), &options).unwrap();
    let mut fresh = encode(&mut new, &[2, 6]);
    new.finish(&mut fresh).unwrap();
    assert!(again == fresh, "a restarted encoder wrote other bytes");
    let (_, frames) = decode_all(&again, &DecoderOptions::default()).unwrap();
    assert_eq!(frames.len(), 2);
}

#[test]
fn the_base_positions_are_snapped_within_the_error_bound() {
    let s = Synthetic::new(20, 1);
    let encoder = Encoder::new(s.header().clone(), &EncoderOptions::default()).unwrap();
    let bound = 0.001 * height(s.header());
    for (snapped, original) in encoder.header().meshes.iter().zip(&s.header().meshes) {
        for (a, b) in snapped.base_positions.iter().zip(&original.base_positions) {
            assert!(distance(*a, *b) <= bound);
        }
    }
}

#[test]
fn quantisation_error_does_not_accumulate_over_500_frames() {
    // A slow drift of a third of a grid step per frame: sending rounded
    // per-frame differences of the *input* would drift by up to half a
    // step every frame; differences against the decoder's state never do.
    let bounds = [[0.0, 0.0, 0.0], [1.0, 10.0, 1.0]];
    let grid = Grid::for_bounds(bounds, 0.001);
    let n = 64;
    let base: Vec<[f32; 3]> = (0..n)
        .map(|i| [i as f32 / n as f32, i as f32 * 0.1, 0.5])
        .collect();
    let header = StreamHeader {
        bounds,
        grid,
        frame_count: 0,
        textures: vec![],
        materials: vec![],
        meshes: vec![Mesh {
            name: "branches".into(),
            uvs: vec![[0.0; 2]; n],
            base_positions: base.clone(),
            ..Mesh::default()
        }],
    };
    let mut encoder = Encoder::new(header, &EncoderOptions::default()).unwrap();
    let mut decoder = Decoder::new(&DecoderOptions::default());
    decoder.push(encoder.header_bytes());
    assert!(matches!(decoder.next_event(), Ok(Some(Event::Header(_)))));
    let drift = grid.step[0] / 3.0;
    let mut worst = 0f64;
    let mut record = Vec::new();
    for i in 0..500u32 {
        let p: Vec<[f32; 3]> = base
            .iter()
            .enumerate()
            .map(|(v, b)| {
                let s = (i + 1) as f32 * drift * (1.0 + v as f32 / n as f32);
                [
                    b[0] + s,
                    b[1] - 0.5 * s,
                    b[2] + (i as f32 * 0.05 + v as f32).sin() * 0.01,
                ]
            })
            .collect();
        record.clear();
        encoder
            .encode_frame(i, 0.5, &[&p], 0.0, &mut record)
            .unwrap();
        decoder.push(&record);
        let Some(Event::Frame(frame)) = decoder.next_event().unwrap() else {
            panic!("frame {i} missing");
        };
        for (got, want) in frame.positions[0].iter().zip(&p) {
            worst = worst.max(distance(*got, *want));
        }
    }
    assert!(
        worst <= f64::from(grid.max_error()) * 1.0001,
        "error {worst} exceeds the grid bound {}",
        grid.max_error()
    );
}

#[test]
fn arbitrary_chunking_gives_the_same_events() {
    let (stream, ..) = synthetic_stream(30, 6, &EncoderOptions::default());
    let whole = events(&stream, &[stream.len()]).unwrap();
    assert_eq!(whole.len(), 1 + 6 + 1);
    for chunks in [&[1][..], &[2, 3, 5, 7], &[13], &[4096], &[1, 999, 17]] {
        assert_eq!(events(&stream, chunks).unwrap(), whole, "chunks {chunks:?}");
    }
}

#[test]
fn every_truncation_is_reported_and_keeps_the_complete_frames() {
    let (stream, ..) = synthetic_stream(3, 4, &EncoderOptions::default());
    let whole = events(&stream, &[stream.len()]).unwrap();
    for cut in 0..stream.len() {
        let mut decoder = Decoder::new(&DecoderOptions::default());
        decoder.push(&stream[..cut]);
        let mut got = Vec::new();
        while let Some(e) = decoder.next_event().unwrap() {
            got.push(e);
        }
        assert_eq!(got[..], whole[..got.len()], "cut at {cut}");
        assert!(got.len() < whole.len());
        let frames = got.iter().filter(|e| matches!(e, Event::Frame(_))).count() as u32;
        assert_eq!(
            decoder.finish(),
            Err(DeltaError::Truncated {
                offset: cut as u64,
                frames
            }),
            "cut at {cut}"
        );
    }
}

#[test]
fn every_single_bit_flip_is_detected() {
    let (stream, ..) = synthetic_stream(2, 3, &EncoderOptions::default());
    for byte in 0..stream.len() {
        for bit in 0..8 {
            let mut damaged = stream.clone();
            damaged[byte] ^= 1 << bit;
            let result = events(&damaged, &[stream.len()]);
            assert!(
                result.is_err(),
                "flip of bit {bit} in byte {byte} went unnoticed"
            );
        }
    }
    // The classification of the common cases.
    let mut damaged = stream.clone();
    damaged[0] ^= 1;
    assert_eq!(events(&damaged, &[64]), Err(DeltaError::BadMagic));
    let mut damaged = stream.clone();
    damaged[4] = 2;
    assert_eq!(
        events(&damaged, &[64]),
        Err(DeltaError::UnsupportedVersion { major: 2, minor: 0 })
    );
    let mut damaged = stream.clone();
    let last = damaged.len() - 6; // inside the end record's payload
    damaged[last] ^= 0x10;
    assert!(matches!(
        events(&damaged, &[64]),
        Err(DeltaError::ChecksumMismatch { frames: 3, .. })
    ));
}

#[test]
fn errors_are_sticky() {
    let (mut stream, ..) = synthetic_stream(2, 2, &EncoderOptions::default());
    stream[20] ^= 0xFF;
    let mut decoder = Decoder::new(&DecoderOptions::default());
    decoder.push(&stream);
    let first = decoder.next_event().unwrap_err();
    assert_eq!(decoder.next_event().unwrap_err(), first);
    assert_eq!(decoder.finish().unwrap_err(), first);
}

/// Splits a stream into its preamble and records `(kind, raw payload)`.
fn records(stream: &[u8]) -> Vec<(u8, Vec<u8>)> {
    let mut out = Vec::new();
    let mut at = PREAMBLE_LEN;
    while at < stream.len() {
        let kind = stream[at];
        let codec = stream[at + 1];
        let stored = u32::from_le_bytes(stream[at + 4..at + 8].try_into().unwrap()) as usize;
        let payload = &stream[at + PREFIX_LEN..at + PREFIX_LEN + stored];
        let raw = if codec == 1 {
            zstd::bulk::decompress(payload, 1 << 26).unwrap()
        } else {
            payload.to_vec()
        };
        out.push((kind, raw));
        at += PREFIX_LEN + stored + 4;
    }
    out
}

/// Reassembles a stream from records, stored, with valid checksums.
fn reframe(records: &[(u8, Vec<u8>)]) -> Vec<u8> {
    let mut out = wire::preamble().to_vec();
    for (kind, raw) in records {
        wire::write_record(&mut out, *kind, raw, None, &mut Vec::new()).unwrap();
    }
    out
}

#[test]
fn reframing_an_unmodified_stream_decodes_the_same() {
    let (stream, ..) = synthetic_stream(5, 3, &EncoderOptions::default());
    assert_eq!(
        events(&reframe(&records(&stream)), &[100]).unwrap(),
        events(&stream, &[100]).unwrap()
    );
}

#[test]
fn a_missing_frame_breaks_the_sequence() {
    let (stream, ..) = synthetic_stream(5, 4, &EncoderOptions::default());
    let mut r = records(&stream);
    r.remove(2); // frame 1
    assert_eq!(
        events(&reframe(&r), &[100]),
        Err(DeltaError::FrameOrder {
            expected: 1,
            found: 2
        })
    );
}

#[test]
fn ancillary_records_are_skipped_and_unknown_critical_ones_refused() {
    let (stream, ..) = synthetic_stream(5, 2, &EncoderOptions::default());
    let mut r = records(&stream);
    r.insert(2, (KIND_ANCILLARY | b'x', b"future metadata".to_vec()));
    assert_eq!(
        events(&reframe(&r), &[100]).unwrap(),
        events(&stream, &[100]).unwrap()
    );
    r[2].0 = b'x';
    assert!(matches!(
        events(&reframe(&r), &[100]),
        Err(DeltaError::Corrupt { .. })
    ));
}

#[test]
fn records_out_of_place_and_trailing_bytes_are_corrupt() {
    let (stream, ..) = synthetic_stream(5, 2, &EncoderOptions::default());
    let r = records(&stream);
    // A frame before the header.
    let swapped = vec![r[1].clone(), r[0].clone(), r[2].clone(), r[3].clone()];
    assert!(matches!(
        events(&reframe(&swapped), &[100]),
        Err(DeltaError::Corrupt { .. })
    ));
    // A second header.
    let twice = vec![r[0].clone(), r[0].clone()];
    assert!(matches!(
        events(&reframe(&twice), &[100]),
        Err(DeltaError::Corrupt { .. })
    ));
    // An end record with the wrong count.
    let mut wrong = r.clone();
    wrong[3].1 = 5u32.to_le_bytes().to_vec();
    assert!(matches!(
        events(&reframe(&wrong), &[100]),
        Err(DeltaError::Corrupt { .. })
    ));
    // Bytes after the end record.
    let mut extra = stream.clone();
    extra.push(0);
    assert!(matches!(
        events(&extra, &[100]),
        Err(DeltaError::Corrupt { .. })
    ));
    // A trailing byte inside a frame payload.
    let mut padded = r.clone();
    padded[1].1.push(0);
    assert!(matches!(
        events(&reframe(&padded), &[100]),
        Err(DeltaError::Corrupt { .. })
    ));
}

#[test]
fn declared_sizes_over_the_limits_are_refused_before_allocating() {
    let (stream, ..) = synthetic_stream(5, 2, &EncoderOptions::default());
    let small = DecoderOptions {
        max_vertices: 10,
        ..DecoderOptions::default()
    };
    let mut decoder = Decoder::new(&small);
    decoder.push(&stream);
    assert!(matches!(
        decoder.next_event(),
        Err(DeltaError::TooLarge {
            what: "vertex count",
            ..
        })
    ));
    // A record declaring 4 GiB is refused from its 12-byte prefix alone.
    let mut huge = wire::preamble().to_vec();
    huge.extend_from_slice(&[b'H', 0, 0, 0]);
    huge.extend_from_slice(&u32::MAX.to_le_bytes());
    huge.extend_from_slice(&u32::MAX.to_le_bytes());
    let mut decoder = Decoder::new(&DecoderOptions::default());
    decoder.push(&huge);
    assert_eq!(
        decoder.next_event(),
        Err(DeltaError::TooLarge {
            what: "record size",
            size: u64::from(u32::MAX),
            limit: 256 << 20
        })
    );
}

#[test]
fn a_zstd_payload_must_declare_its_exact_size() {
    let (stream, ..) = synthetic_stream(5, 1, &EncoderOptions::default());
    let r = records(&stream);
    // A frame payload compressed honestly but declared one byte longer.
    let payload = zstd::bulk::compress(&r[1].1, 1).unwrap();
    let mut out = wire::preamble().to_vec();
    wire::write_record(&mut out, r[0].0, &r[0].1, None, &mut Vec::new()).unwrap();
    let start = out.len();
    out.extend_from_slice(&[b'F', 1, 0, 0]);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&(r[1].1.len() as u32 + 1).to_le_bytes());
    out.extend_from_slice(&payload);
    let crc = wire::record_crc(b'F', &out[start..], &wire::preamble());
    out.extend_from_slice(&crc.to_le_bytes());
    let mut decoder = Decoder::new(&DecoderOptions::default());
    decoder.push(&out);
    assert!(matches!(decoder.next_event(), Ok(Some(Event::Header(_)))));
    assert!(matches!(
        decoder.next_event(),
        Err(DeltaError::Corrupt { .. })
    ));
}

fn tiny_header() -> StreamHeader {
    let bounds = [[0.0; 3], [1.0; 3]];
    StreamHeader {
        bounds,
        grid: Grid::for_bounds(bounds, 0.001),
        frame_count: 0,
        textures: vec![Texture {
            png: TINY_PNG.to_vec(),
        }],
        materials: vec![Material {
            texture: Some(0),
            ..Material::default()
        }],
        meshes: vec![Mesh {
            name: "leaves".into(),
            indices: vec![0, 1, 2],
            uvs: vec![[0.0; 2]; 3],
            groups: vec![MaterialGroup {
                first: 0,
                count: 3,
                material: 0,
                fade_to: None,
            }],
            base_positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        }],
    }
}

#[test]
fn inconsistent_headers_are_the_callers_mistake() {
    let options = EncoderOptions::default();
    assert!(Encoder::new(tiny_header(), &options).is_ok());
    let cases: Vec<(&str, Box<dyn Fn(&mut StreamHeader)>)> = vec![
        ("index", Box::new(|h| h.meshes[0].indices[2] = 3)),
        ("triangles", Box::new(|h| h.meshes[0].indices.push(0))),
        (
            "uvs",
            Box::new(|h| h.meshes[0].uvs.pop().map(drop).unwrap_or(())),
        ),
        ("group range", Box::new(|h| h.meshes[0].groups[0].count = 6)),
        (
            "material",
            Box::new(|h| h.meshes[0].groups[0].fade_to = Some(1)),
        ),
        (
            "texture ref",
            Box::new(|h| h.materials[0].texture = Some(1)),
        ),
        ("png", Box::new(|h| h.textures[0].png[1] = b'Q')),
        (
            "colour",
            Box::new(|h| h.materials[0].base_color[0] = f32::NAN),
        ),
        (
            "cutoff",
            Box::new(|h| h.materials[0].alpha_mode = AlphaMode::Mask { cutoff: 2.0 }),
        ),
        ("step", Box::new(|h| h.grid.step[1] = 0.0)),
        ("bounds", Box::new(|h| h.bounds[0][0] = 2.0)),
        (
            "position",
            Box::new(|h| h.meshes[0].base_positions[1][2] = f32::INFINITY),
        ),
        (
            "off grid",
            Box::new(|h| h.meshes[0].base_positions[1][2] = 1e9),
        ),
    ];
    for (name, break_it) in cases {
        let mut header = tiny_header();
        break_it(&mut header);
        assert!(
            matches!(
                Encoder::new(header, &options),
                Err(DeltaError::InvalidHeader(_))
            ),
            "{name}"
        );
    }
}

#[test]
fn invalid_frames_are_refused_without_changing_the_state() {
    let mut encoder = Encoder::new(tiny_header(), &EncoderOptions::default()).unwrap();
    let good = [[0.0, 0.0, 0.1], [1.0, 0.0, 0.1], [0.0, 1.0, 0.1]];
    let mut bad = good;
    bad[2][1] = f32::NAN;
    let mut out = Vec::new();
    let invalid =
        |r: Result<(), DeltaError>| matches!(r, Err(DeltaError::InvalidFrame { index: 0, .. }));
    assert!(invalid(encoder.encode_frame(
        0,
        0.0,
        &[&bad],
        0.0,
        &mut out
    )));
    assert!(invalid(encoder.encode_frame(
        0,
        0.0,
        &[&good[..2]],
        0.0,
        &mut out
    )));
    assert!(invalid(encoder.encode_frame(
        0,
        0.0,
        &[&good, &good],
        0.0,
        &mut out
    )));
    assert!(invalid(encoder.encode_frame(
        0,
        1.5,
        &[&good],
        0.0,
        &mut out
    )));
    assert!(invalid(encoder.encode_frame(
        0,
        0.0,
        &[&good],
        -0.1,
        &mut out
    )));
    assert!(out.is_empty());
    assert_eq!(
        encoder.encode_frame(1, 0.0, &[&good], 0.0, &mut out),
        Err(DeltaError::FrameOrder {
            expected: 0,
            found: 1
        })
    );
    let mut stream = encoder.header_bytes().to_vec();
    encoder
        .encode_frame(0, 0.0, &[&good], 0.0, &mut stream)
        .unwrap();
    encoder.finish(&mut stream).unwrap();
    assert_eq!(encoder.finish(&mut stream), Err(DeltaError::Finished));
    assert_eq!(
        encoder.encode_frame(1, 0.0, &[&good], 0.0, &mut stream),
        Err(DeltaError::Finished)
    );
    let (_, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    assert_eq!(frames[0].positions, encoder.reconstructed_positions());
}

#[test]
fn finishing_short_of_the_announced_frame_count_is_refused() {
    let mut header = tiny_header();
    header.frame_count = 2;
    let mut encoder = Encoder::new(header, &EncoderOptions::default()).unwrap();
    let p = [[0.0; 3]; 3];
    let mut out = Vec::new();
    encoder.encode_frame(0, 0.0, &[&p], 0.0, &mut out).unwrap();
    assert!(matches!(
        encoder.finish(&mut out),
        Err(DeltaError::InvalidFrame { .. })
    ));
}

#[test]
fn per_frame_buffers_do_not_grow_after_the_first_frame() {
    let s = Synthetic::new(200, 10);
    let mut encoder = Encoder::new(s.header().clone(), &EncoderOptions::default()).unwrap();
    let mut p = Vec::new();
    let mut out = Vec::new();
    let mut capacities = None;
    for i in 0..10 {
        s.positions(time(i, 10), &mut p);
        out.clear();
        encoder
            .encode_frame(i, 0.0, &slices(&p), 0.0, &mut out)
            .unwrap();
        let now = encoder.buffer_capacities();
        // The encoder's buffers are sized up front for the largest frame.
        assert_eq!(*capacities.get_or_insert(now), now, "frame {i}");
    }
}

#[test]
fn empty_meshes_and_zero_frames_are_valid_streams() {
    let mut header = tiny_header();
    header.meshes.push(Mesh {
        name: "leaves".into(),
        ..Mesh::default()
    });
    let mut encoder = Encoder::new(header.clone(), &EncoderOptions::default()).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    encoder.finish(&mut stream).unwrap();
    let (decoded, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    assert_eq!(decoded.meshes.len(), 2);
    assert!(frames.is_empty());
}

#[test]
fn a_mesh_larger_than_one_block_round_trips() {
    // Blocks of 4096 vertices: cover the boundary with a partial last block.
    let n = BLOCK * 2 + 17;
    let bounds = [[-5.0; 3], [5.0; 3]];
    let base: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            [
                (i as f32 * 0.37).sin() * 4.0,
                (i as f32 * 0.11).cos() * 4.0,
                0.0,
            ]
        })
        .collect();
    let header = StreamHeader {
        bounds,
        grid: Grid::for_bounds(bounds, 0.001),
        frame_count: 2,
        textures: vec![],
        materials: vec![],
        meshes: vec![Mesh {
            name: "branches".into(),
            indices: (0..n as u32 - 2).flat_map(|i| [i, i + 1, i + 2]).collect(),
            uvs: vec![[0.5; 2]; n],
            groups: vec![],
            base_positions: base.clone(),
        }],
    };
    let mut encoder = Encoder::new(header, &EncoderOptions::default()).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    let moved: Vec<[f32; 3]> = base
        .iter()
        .enumerate()
        .map(|(i, p)| [p[0], p[1], if i % 1000 == 0 { 4.9 } else { 0.01 }])
        .collect();
    encoder
        .encode_frame(0, 0.0, &[&base], 0.0, &mut stream)
        .unwrap();
    encoder
        .encode_frame(1, 1.0, &[&moved], 1.0, &mut stream)
        .unwrap();
    encoder.finish(&mut stream).unwrap();
    let (header, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    assert_eq!(header, *encoder.header());
    assert_eq!(frames[1].positions, encoder.reconstructed_positions());
}

#[test]
fn parallel_encoding_writes_the_bytes_of_a_sequential_pass() {
    // 3,000 chains: 180,000 vertices, enough for several runs of blocks,
    // with a partial last block; one position far off so a run boundary
    // carries a large predictor value.
    let s = Synthetic::new(3_000, 3);
    let mut streams = Vec::new();
    for workers in [1, 2, 3, 7] {
        let mut encoder = Encoder::new(s.header().clone(), &EncoderOptions::default()).unwrap();
        encoder.limit_workers(workers);
        let mut stream = encoder.header_bytes().to_vec();
        let mut p = Vec::new();
        for i in 0..3 {
            s.positions(time(i, 3), &mut p);
            p[0][BLOCK * 7 - 1][1] += 3.0;
            encoder
                .encode_frame(i, time(i, 3), &slices(&p), 0.0, &mut stream)
                .unwrap();
        }
        encoder.finish(&mut stream).unwrap();
        streams.push(stream);
    }
    for (workers, stream) in [2, 3, 7].iter().zip(&streams[1..]) {
        assert!(*stream == streams[0], "{workers} workers");
    }
    decode_all(&streams[0], &DecoderOptions::default()).unwrap();
}

#[test]
fn an_off_grid_position_in_a_parallel_run_is_refused() {
    let s = Synthetic::new(3_000, 2);
    let mut encoder = Encoder::new(s.header().clone(), &EncoderOptions::default()).unwrap();
    encoder.limit_workers(3);
    let mut p = Vec::new();
    s.positions(0.0, &mut p);
    let last = p[0].len() - 1;
    p[0][last] = [f32::NAN, 0.0, 0.0];
    let mut out = Vec::new();
    assert!(matches!(
        encoder.encode_frame(0, 0.0, &slices(&p), 0.0, &mut out),
        Err(DeltaError::InvalidFrame { .. })
    ));
    assert!(out.is_empty());
    assert_eq!(encoder.next_index(), 0);
}

#[test]
fn grid_error_bound_holds_for_points_inside_the_bounds() {
    let mut runner = proptest::test_runner::TestRunner::default();
    runner
        .run(
            &(
                prop::array::uniform3(-100.0f32..100.0),
                prop::array::uniform3(0.01f32..50.0),
                prop::collection::vec(prop::array::uniform3(0.0f32..1.0), 1..50),
            ),
            |(min, size, points)| {
                let max = [0, 1, 2].map(|a| min[a] + size[a]);
                let grid = Grid::for_bounds([min, max], 0.001);
                let height = f64::from(max[1] - min[1]);
                for f in points {
                    let p = [0, 1, 2].map(|a| min[a] + f[a] * size[a]);
                    let q = grid.quantise(p).expect("inside the bounds");
                    // Far from the origin a flat box's bound is finer than
                    // f32 itself: allow the reconstruction's own rounding.
                    let magnitude = p.iter().fold(0f32, |m, c| m.max(c.abs()));
                    let rounding = 4.0 * f64::from(f32::EPSILON * magnitude);
                    prop_assert!(distance(grid.dequantise(q), p) <= 0.001 * height + rounding);
                }
                Ok(())
            },
        )
        .unwrap();
}

fn arb_stream() -> impl Strategy<Value = (StreamHeader, Vec<Vec<Vec<[f32; 3]>>>)> {
    let mesh = (0usize..40, 0usize..30).prop_flat_map(|(n, triangles)| {
        let n = n.max(1);
        (
            prop::collection::vec(prop::array::uniform3(-2.0f32..2.0), n),
            prop::collection::vec(0..n as u32, triangles * 3),
        )
    });
    (
        prop::collection::vec(mesh, 1..3),
        0usize..6,
        prop::collection::vec(-0.3f32..0.3, 3),
    )
        .prop_map(|(meshes, frames, motion)| {
            let bounds = [[-3.0; 3], [3.0; 3]];
            let header = StreamHeader {
                bounds,
                grid: Grid::for_bounds(bounds, 0.001),
                frame_count: frames as u32,
                textures: vec![],
                materials: vec![Material::default()],
                meshes: meshes
                    .iter()
                    .enumerate()
                    .map(|(m, (base, indices))| Mesh {
                        name: format!("mesh{m}"),
                        indices: indices.clone(),
                        uvs: base.iter().map(|p| [p[0], p[1]]).collect(),
                        groups: vec![MaterialGroup {
                            first: 0,
                            count: indices.len() as u32,
                            material: 0,
                            fade_to: Some(0),
                        }],
                        base_positions: base.clone(),
                    })
                    .collect(),
            };
            let frames = (0..frames)
                .map(|f| {
                    meshes
                        .iter()
                        .map(|(base, _)| {
                            base.iter()
                                .enumerate()
                                .map(|(i, p)| {
                                    let s = (f as f32 + 1.0) * (1.0 + (i % 3) as f32);
                                    [
                                        p[0] + motion[0] * s * 0.1,
                                        p[1] + motion[1] * s * 0.1,
                                        p[2] + motion[2] * (i as f32).sin(),
                                    ]
                                })
                                .collect()
                        })
                        .collect()
                })
                .collect();
            (header, frames)
        })
}

fn encode_all(
    header: &StreamHeader,
    frames: &[Vec<Vec<[f32; 3]>>],
) -> (Vec<u8>, Encoder, Vec<Vec<Vec<[f32; 3]>>>) {
    let mut encoder = Encoder::new(header.clone(), &EncoderOptions::default()).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    let mut tracked = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        encoder
            .encode_frame(i as u32, 0.5, &slices(f), 0.25, &mut stream)
            .unwrap();
        tracked.push(encoder.reconstructed_positions());
    }
    encoder.finish(&mut stream).unwrap();
    (stream, encoder, tracked)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn random_meshes_round_trip((header, frames) in arb_stream(), chunk in 1usize..200) {
        let (stream, encoder, tracked) = encode_all(&header, &frames);
        let events = events(&stream, &[chunk]).unwrap();
        prop_assert_eq!(&events[0], &Event::Header(Box::new(encoder.header().clone())));
        prop_assert_eq!(events.len(), frames.len() + 2);
        let bound = 0.001 * height(&header);
        for (i, event) in events[1..=frames.len()].iter().enumerate() {
            let Event::Frame(frame) = event else { panic!("not a frame") };
            prop_assert_eq!(&frame.positions, &tracked[i]);
            for (got, want) in frame.positions.iter().flatten().zip(frames[i].iter().flatten()) {
                prop_assert!(distance(*got, *want) <= bound);
            }
        }
        prop_assert_eq!(events.last(), Some(&Event::End { frames: frames.len() as u32 }));
    }

    #[test]
    fn mutated_streams_never_panic(
        (header, frames) in arb_stream(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        chunk in 1usize..300,
    ) {
        let (stream, ..) = encode_all(&header, &frames);
        let clean = events(&stream, &[stream.len()]).unwrap();
        let mut damaged = stream.clone();
        for (at, value) in &flips {
            damaged[at.index(stream.len())] = *value;
        }
        // Either an error, or (a mutation in an ignored field) the
        // very same events.
        if let Ok(got) = events(&damaged, &[chunk]) {
            prop_assert_eq!(got, clean);
        }
    }

    #[test]
    fn mutated_payloads_with_valid_checksums_never_panic(
        (header, frames) in arb_stream(),
        record in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<Option<prop::sample::Index>>(),
    ) {
        // Past the checksum: the parser itself must hold against hostile
        // but well-framed payloads (errors or some other valid stream).
        let (stream, ..) = encode_all(&header, &frames);
        let mut r = records(&stream);
        let i = record.index(r.len());
        if !r[i].1.is_empty() {
            for (at, value) in &flips {
                let len = r[i].1.len();
                r[i].1[at.index(len)] = *value;
            }
            if let Some(cut) = cut {
                let len = r[i].1.len();
                r[i].1.truncate(cut.index(len));
            }
        }
        let _ = events(&reframe(&r), &[97]);
    }
}
