//! glTF output (in progress).
