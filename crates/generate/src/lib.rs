//! Procedural tree generator (in progress).
