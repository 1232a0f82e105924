//! Byte mutations for the loaders' fuzz tests (`files/fuzz_loaders.rs` here, and w3d-diffusion's
//! `errors_cases/fuzz_weights.rs`, whose test binary includes this file): flips, overwrites, little-endian integers
//! at any offset, truncation, inserted tokens (numbers, JSON fragments, huge counts),
//! duplicated and removed chunks, drawn by proptest.
#![allow(dead_code)]

use std::path::Path;
use std::time::{Duration, Instant};

use proptest::prelude::*;

/// Writes `bytes` as `name` in a fresh folder and runs `load` on its path, failing the test
/// when the load takes `bound` or longer (a loader must not hang on damaged input).
pub fn timed<T>(name: &str, bytes: &[u8], bound: Duration, load: impl FnOnce(&Path) -> T) -> T {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    let start = Instant::now();
    let result = load(&path);
    let elapsed = start.elapsed();
    assert!(elapsed < bound, "{name} ({} bytes) took {elapsed:?}", bytes.len());
    result
}

/// Interesting things to insert into text and binary formats alike.
pub const TOKENS: [&[u8]; 20] = [
    b" -1",
    b" 0",
    b" 4294967295",
    b" 1000000000",
    b" nan",
    b" inf",
    b" 1e39",
    b"\n",
    b"\nf 1 2 3\n",
    b"\nf 1/1 2//2 3\n",
    b"\nelement junk 1000000000000000000\n",
    b"\xff\xff\xff\xff",
    b"\x00\x00\x00\x00",
    b"\x00\xca\x9a\x3b",
    b"\"count\": 1000000000,",
    b"{}",
    b"[]",
    b"null",
    b"\"hidden_size\": 400000,",
    b"\"shape\": [1000000000, 1000000000],",
];

#[derive(Debug, Clone)]
pub enum Mutation {
    /// Flip one bit of the byte at (position mod length).
    Flip(usize, u8),
    /// Overwrite a byte.
    Set(usize, u8),
    /// Overwrite 4 bytes with a little-endian u32 (lengths, counts, offsets).
    SetU32(usize, u32),
    /// Keep only the first (position mod length) bytes.
    Truncate(usize),
    /// Insert one of [`TOKENS`].
    Insert(usize, usize),
    /// Copy a chunk (start, length) to another position.
    Duplicate(usize, usize, usize),
    /// Remove a chunk (start, length).
    Remove(usize, usize),
}

pub fn mutation() -> impl Strategy<Value = Mutation> {
    let at = any::<usize>();
    prop_oneof![
        (at, 0u8..8).prop_map(|(i, b)| Mutation::Flip(i, b)),
        (at, any::<u8>()).prop_map(|(i, v)| Mutation::Set(i, v)),
        (at, prop_oneof![Just(0u32), Just(1), Just(u32::MAX), Just(1_000_000_000), Just(0x7fff_ffff), any::<u32>()])
            .prop_map(|(i, v)| Mutation::SetU32(i, v)),
        at.prop_map(Mutation::Truncate),
        (at, 0..TOKENS.len()).prop_map(|(i, t)| Mutation::Insert(i, t)),
        (at, 1usize..64, at).prop_map(|(s, l, d)| Mutation::Duplicate(s, l, d)),
        (at, 1usize..64).prop_map(|(s, l)| Mutation::Remove(s, l)),
    ]
}

pub fn mutations() -> impl Strategy<Value = Vec<Mutation>> {
    prop::collection::vec(mutation(), 1..5)
}

pub fn apply(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for m in mutations {
        let n = b.len().max(1);
        match *m {
            Mutation::Flip(i, bit) if !b.is_empty() => b[i % n] ^= 1 << bit,
            Mutation::Set(i, v) if !b.is_empty() => b[i % n] = v,
            Mutation::SetU32(i, v) if b.len() >= 4 => {
                let at = i % (b.len() - 3);
                b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
            Mutation::Truncate(i) => b.truncate(i % n),
            Mutation::Insert(i, t) => {
                let at = i % (b.len() + 1);
                b.splice(at..at, TOKENS[t].iter().copied());
            }
            Mutation::Duplicate(s, l, d) if !b.is_empty() => {
                let s = s % b.len();
                let chunk: Vec<u8> = b[s..(s + l).min(b.len())].to_vec();
                let d = d % (b.len() + 1);
                b.splice(d..d, chunk);
            }
            Mutation::Remove(s, l) if !b.is_empty() => {
                let s = s % b.len();
                b.drain(s..(s + l).min(b.len()));
            }
            _ => {}
        }
    }
    b
}
