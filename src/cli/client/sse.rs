//! A small incremental parser for `text/event-stream` (Server-Sent Events).
//!
//! Hand-written rather than a dependency: no SSE crate is in `Cargo.lock`,
//! the format is a few lines of the WHATWG HTML standard ("Event stream
//! interpretation"), and the client needs exactly two things a generic
//! crate would hide or make awkward — feeding it arbitrary byte chunks from
//! `reqwest::Response::chunk` (a line may be split anywhere, even between
//! the `\r` and `\n` of one line ending) and reading the last event id for
//! `Last-Event-ID` when it reconnects.
//!
//! What it implements: lines end in CRLF, LF or CR; `:` starts a comment
//! (the server's keep-alives); `field: value` with one optional space
//! after the colon; the `event`, `data`, `id` and `retry` fields (others
//! ignored); a blank line dispatches the event if it has data, `data`
//! lines are joined with `\n`, and the id persists across events as the
//! standard says. A leading UTF-8 byte-order mark is skipped. Lines longer
//! than [`MAX_LINE`] are an error rather than unbounded memory.

use std::time::Duration;

/// The longest line accepted (bytes). The server's largest event is a job
/// document of a few kilobytes.
pub const MAX_LINE: usize = 4 << 20;

/// One dispatched event.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SseEvent {
    /// The event type (`message` when the stream named none).
    pub event: String,
    /// The data lines, joined with `\n`.
    pub data: String,
}

/// The stream broke the parser's limits.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("an event-stream line is longer than {MAX_LINE} bytes")]
pub struct LineTooLong;

/// An incremental event-stream parser: feed it chunks with [`push`].
///
/// [`push`]: SseParser::push
#[derive(Debug, Default)]
pub struct SseParser {
    /// Bytes of the current, not yet terminated line.
    line: Vec<u8>,
    /// The previous chunk ended in `\r`: a `\n` at the start of the next
    /// chunk ends the same line, not an empty one.
    after_cr: bool,
    /// Whether the stream's first bytes were looked at (for the BOM).
    started: bool,
    event: String,
    data: String,
    has_data: bool,
    last_id: Option<String>,
    retry: Option<Duration>,
}

impl SseParser {
    /// A parser at the start of a stream.
    pub fn new() -> SseParser {
        SseParser::default()
    }

    /// Parses `bytes`, appending every event they complete to `out`.
    pub fn push(&mut self, mut bytes: &[u8], out: &mut Vec<SseEvent>) -> Result<(), LineTooLong> {
        if !self.started {
            // The BOM may itself arrive split; wait for three bytes.
            let mut probe = self.line.clone();
            probe.extend_from_slice(bytes);
            if probe.len() < 3 && b"\xEF\xBB\xBF".starts_with(&probe) {
                self.line = probe;
                return Ok(());
            }
            self.started = true;
            if let Some(rest) = probe.strip_prefix(b"\xEF\xBB\xBF") {
                self.line.clear();
                return self.push(rest, out);
            }
            // No BOM: `self.line` is a prefix of `probe`; carry on normally.
        }
        if self.after_cr && !bytes.is_empty() {
            self.after_cr = false;
            if let Some(rest) = bytes.strip_prefix(b"\n") {
                bytes = rest;
            }
        }
        while let Some(end) = bytes.iter().position(|&b| b == b'\n' || b == b'\r') {
            self.append(&bytes[..end])?;
            let line = std::mem::take(&mut self.line);
            self.process(&line, out);
            self.line = line;
            self.line.clear();
            if bytes[end] == b'\r' {
                match bytes.get(end + 1) {
                    Some(b'\n') => bytes = &bytes[end + 2..],
                    Some(_) => bytes = &bytes[end + 1..],
                    None => {
                        self.after_cr = true;
                        bytes = &[];
                    }
                }
            } else {
                bytes = &bytes[end + 1..];
            }
        }
        self.append(bytes)
    }

    /// The id of the last event (what `Last-Event-ID` carries).
    pub fn last_event_id(&self) -> Option<&str> {
        self.last_id.as_deref()
    }

    /// The reconnection delay the server asked for, if it did.
    pub fn retry(&self) -> Option<Duration> {
        self.retry
    }

    fn append(&mut self, bytes: &[u8]) -> Result<(), LineTooLong> {
        if self.line.len() + bytes.len() > MAX_LINE {
            return Err(LineTooLong);
        }
        self.line.extend_from_slice(bytes);
        Ok(())
    }

    fn process(&mut self, line: &[u8], out: &mut Vec<SseEvent>) {
        if line.is_empty() {
            if self.has_data {
                out.push(SseEvent {
                    event: if self.event.is_empty() {
                        "message".to_owned()
                    } else {
                        std::mem::take(&mut self.event)
                    },
                    data: std::mem::take(&mut self.data),
                });
            }
            self.event.clear();
            self.data.clear();
            self.has_data = false;
            return;
        }
        if line[0] == b':' {
            return;
        }
        let line = String::from_utf8_lossy(line);
        let (field, value) = match line.split_once(':') {
            Some((field, value)) => (field, value.strip_prefix(' ').unwrap_or(value)),
            None => (&*line, ""),
        };
        match field {
            "event" => value.clone_into(&mut self.event),
            "data" => {
                if self.has_data {
                    self.data.push('\n');
                }
                self.data.push_str(value);
                self.has_data = true;
            }
            "id" if !value.contains('\0') => self.last_id = Some(value.to_owned()),
            "retry" if !value.is_empty() && value.bytes().all(|b| b.is_ascii_digit()) => {
                if let Ok(ms) = value.parse() {
                    self.retry = Some(Duration::from_millis(ms));
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_chunks(chunks: &[&[u8]]) -> Vec<SseEvent> {
        let mut parser = SseParser::new();
        let mut out = Vec::new();
        for chunk in chunks {
            parser.push(chunk, &mut out).unwrap();
        }
        out
    }

    fn ev(event: &str, data: &str) -> SseEvent {
        SseEvent {
            event: event.into(),
            data: data.into(),
        }
    }

    #[test]
    fn parses_named_events_comments_and_multiline_data() {
        let stream = b": keep-alive\n\nevent: job\ndata: {\"a\":1}\n\ndata: one\ndata:two\n\n";
        assert_eq!(
            parse_chunks(&[stream]),
            [ev("job", "{\"a\":1}"), ev("message", "one\ntwo")]
        );
    }

    #[test]
    fn every_split_point_and_line_ending_gives_the_same_events() {
        let expected = [ev("stage", "x"), ev("done", "")];
        for ending in ["\n", "\r\n", "\r"] {
            let text = format!(
                "\u{feff}id: 7{e}event: stage{e}data: x{e}{e}event: done{e}data{e}{e}",
                e = ending
            );
            let bytes = text.as_bytes();
            for cut in 0..=bytes.len() {
                for cut2 in cut..=bytes.len() {
                    let got = parse_chunks(&[&bytes[..cut], &bytes[cut..cut2], &bytes[cut2..]]);
                    assert_eq!(got, expected, "ending {ending:?}, cuts {cut} {cut2}");
                }
            }
        }
    }

    #[test]
    fn incomplete_events_and_events_without_data_are_not_dispatched() {
        assert_eq!(parse_chunks(&[b"event: job\n\n"]), []);
        assert_eq!(parse_chunks(&[b"event: job\ndata: x\n"]), []);
    }

    #[test]
    fn id_and_retry_are_remembered() {
        let mut parser = SseParser::new();
        let mut out = Vec::new();
        parser
            .push(b"id: 41\nretry: 250\nretry: soon\ndata: a\n\n", &mut out)
            .unwrap();
        assert_eq!(parser.last_event_id(), Some("41"));
        assert_eq!(parser.retry(), Some(Duration::from_millis(250)));
        parser.push(b"id\n", &mut out).unwrap();
        assert_eq!(parser.last_event_id(), Some(""));
    }

    #[test]
    fn overlong_lines_are_refused() {
        let mut parser = SseParser::new();
        let mut out = Vec::new();
        let chunk = vec![b'a'; 1 << 20];
        let mut result = Ok(());
        for _ in 0..=(MAX_LINE >> 20) {
            result = parser.push(&chunk, &mut out);
        }
        assert_eq!(result, Err(LineTooLong));
    }

    #[test]
    fn invalid_utf8_does_not_panic() {
        assert_eq!(
            parse_chunks(&[b"data: \xff\xfe\n\n"]),
            [ev("message", "\u{fffd}\u{fffd}")]
        );
    }
}
