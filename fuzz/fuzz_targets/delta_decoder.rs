//! The incremental delta-stream decoder (`treemorph_api::delta::Decoder`)
//! on untrusted bytes in arbitrary chunks — what the web viewer and the CLI
//! client do with `GET /v1/jobs/{id}/stream`.
//!
//! The first byte seeds the chunk sizes (1 to 256 bytes, varying), the rest
//! is the stream.
//!
//! Invariants: never a panic; feeding the bytes in chunks yields exactly
//! the events, error and completeness of [`decode_all`] on the whole.
#![no_main]

use libfuzzer_sys::fuzz_target;
use treemorph_api::delta::{Decoder, DecoderOptions, Event, decode_all};

fuzz_target!(|data: &[u8]| {
    let Some((&seed, stream)) = data.split_first() else {
        return;
    };
    let options = DecoderOptions::default();
    let whole = decode_all(stream, &options);

    let mut decoder = Decoder::new(&options);
    let mut events: Vec<Event> = Vec::new();
    let mut error = None;
    let mut at = 0;
    let mut state = u32::from(seed) | 1;
    'feed: while at < stream.len() {
        // xorshift: a different chunk size each time, reproducible.
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let n = (state % 256) as usize + 1;
        let end = (at + n).min(stream.len());
        decoder.push(&stream[at..end]);
        at = end;
        loop {
            match decoder.next_event() {
                Ok(Some(event)) => events.push(event),
                Ok(None) => break,
                Err(e) => {
                    // Errors are sticky.
                    assert_eq!(decoder.next_event(), Err(e.clone()));
                    error = Some(e);
                    break 'feed;
                }
            }
        }
    }
    let finished = match error {
        Some(e) => Err(e),
        None => decoder.finish(),
    };
    match whole {
        Ok((header, frames)) => {
            assert_eq!(finished, Ok(()), "chunked decoding failed, whole succeeded");
            assert!(decoder.is_complete());
            let mut expected = vec![Event::Header(Box::new(header))];
            expected.extend(frames.into_iter().map(Event::Frame));
            let n = expected.len() as u32 - 1;
            expected.push(Event::End { frames: n });
            assert!(events == expected, "chunked events differ from decode_all");
        }
        Err(e) => {
            // The same error, wherever the input was cut. Truncation is
            // reported at the same offset either way.
            assert_eq!(finished, Err(e), "chunked decoding disagrees with decode_all");
        }
    }
});
