//! Matrix products with bfloat16 factors and f32 sums, on CPUs with AVX-512 BF16: what
//! [`crate::compute::Products::Bf16`] runs for the fully connected layers
//! ([`crate::nn::Linear`]) and the convolutions ([`crate::nn::Conv2d`]) at inference.
//!
//! Why: `vdpbf16ps` multiplies 16 pairs of bf16 values per 512-bit instruction and adds each
//! pair's two products to an f32 lane, 32 multiply-adds where an f32 FMA does 16, at the same
//! rate (measured on the 2-core Zen 5 EPYC this was written on: two of either per cycle), so
//! a product whose time goes to multiply-adds can run up to twice as fast. The factors lose
//! precision (8 bits of mantissa, a relative rounding of at most 2⁻⁹ each); the sums keep
//! f32's.
//!
//! How: `C[m, n] = A[m, k]·B[k, n]` with both factors rounded to bf16 (to nearest, ties to
//! even; a NaN stays a NaN) while they are *packed* into the layout the instruction reads:
//! consecutive `k` taken in pairs, each pair one 32-bit word (the even `k` in the low half).
//! - `A` in micro-panels of [`MR`] rows: per pair, the `MR` rows' words in row order, so the
//!   micro-kernel broadcasts one word to all 16 lanes;
//! - `B` in panels of [`NR`] columns: per pair, the `NR` columns' words in column order, two
//!   512-bit loads;
//! - the micro-kernel keeps an `MR × NR` tile of `C` in 28 of the 32 vector registers and runs
//!   over up to [`KC_PAIRS`] pairs, so that the `B` panel it reads (16 KiB) stays in the
//!   first-level cache while it is reused for the micro-panels of `A`.
//!
//! One factor is a layer's weight, packed whole once per call, straight from the dtype it is
//! held in (f32, or f16 for [`crate::WeightStorage::AsStored`] models: f16 → f32 → bf16 a few
//! thousand values at a time, no f32 copy of the weight); the other holds the activations. For
//! a fully connected layer the activations are `A` (rows of tokens) and the weight `B`. For a
//! convolution the weight is `A` (`[out, in·k²]`) and the activations `B`: the columns of the
//! im2col matrix, built block by block straight from the image (each kernel tap's row for a
//! few hundred output pixels at a time), so the column matrix is never made in f32.
//!
//! Work is split over rayon's pool by blocks of activation lines (up to [`MAX_BLOCK_PANELS`]
//! panels, so that each weight value fetched serves a whole block) and, when those blocks are
//! too few for the pool, by ranges of weight lines too; the activations are then packed once
//! for all tasks instead of by each. Each task computes its block of `C` in a buffer of its
//! own, a group of weight panels at a time (the group's part of the block sized for the
//! second-level cache), then copies it, adding the bias, into the parts of the output it owns,
//! which are disjoint slices.
//!
//! A portable micro-kernel computes the same products on CPUs without the instructions, for
//! the tests only: the layers take this path only where [`crate::compute::Products::supported`]
//! says the CPU has them (elsewhere their products stay f32).

use std::cell::RefCell;
use std::ops::Range;

use burn::backend::Flex;
use burn::tensor::{DType, Tensor, TensorData};
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use crate::compute::{self, Products, WorkKind};
use crate::kernels::conv_shape::ConvShape;
use crate::kernels::dispatch::{cpu_inference_f32, on_cpu_backend};

/// Rows of `C` (and of `A`) one micro-kernel call computes: 14 rows × 2 vectors = 28
/// accumulator registers, leaving 4 of the 32 for the two vectors of `B` and the broadcast.
pub(crate) const MR: usize = 14;
/// Columns of `C` (and of `B`) one micro-kernel call computes: two vectors of 16 f32 lanes.
pub(crate) const NR: usize = 32;
/// Largest number of `k` pairs one micro-kernel call runs over (256 values of `k`): a `B`
/// panel of `NR × KC_PAIRS` words is 16 KiB, a third of Zen 5's first-level data cache.
pub(crate) const KC_PAIRS: usize = 128;
/// Largest number of activation panels (of [`MR`] rows or [`NR`] columns) in one block: 112
/// rows or 256 columns. The weight's bytes fetched per multiply-add fall as the block widens;
/// one pass over `k` of the packed block stays at most 128 KiB, in the second-level cache.
pub(crate) const MAX_BLOCK_PANELS: usize = 8;
/// Bytes of a task's block of `C` one group of weight panels covers: with the packed
/// activations of one pass over `k` and the group's weight panels, about half the
/// second-level cache (1 MiB per core on Zen 4 and Zen 5).
const C_GROUP_BYTES: usize = 256 << 10;
/// Parallel tasks wanted per thread of the pool: enough that the blocks' unequal sizes even
/// out between the cores.
const TASKS_PER_THREAD: usize = 4;

// ---------------------------------------------------------------------------------------------
// Rounding.

/// The bf16 value nearest `x` (ties to even) as its 16 bits, in the low half of the word; a
/// NaN stays a (quiet) NaN of the same sign instead of rounding to an infinity.
#[inline(always)]
pub(crate) fn bf16_bits(x: f32) -> u32 {
    let bits = x.to_bits();
    let rounded = bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16;
    let quiet_nan = (bits >> 16) | 0x40;
    if bits & 0x7fff_ffff > 0x7f80_0000 { quiet_nan } else { rounded }
}

/// The f32 value of bf16 bits (exact: bf16 is f32 without the low 16 bits).
#[inline(always)]
pub(crate) fn bf16_value(bits: u32) -> f32 {
    f32::from_bits((bits & 0xffff) << 16)
}

/// `x` rounded to bf16, as an f32 (what the products see of a factor).
#[cfg(test)]
pub(crate) fn round_bf16(x: f32) -> f32 {
    bf16_value(bf16_bits(x))
}

/// One packed word: `lo` (the even `k`) in the low half, `hi` in the high half, both rounded.
#[inline(always)]
fn pair(lo: f32, hi: f32) -> u32 {
    bf16_bits(lo) | (bf16_bits(hi) << 16)
}

/// `out[j] = pair(lo[j], hi[j])`.
#[inline(always)]
fn pair_rows_portable(lo: &[f32], hi: &[f32], out: &mut [u32]) {
    for ((o, &l), &h) in out.iter_mut().zip(lo).zip(hi) {
        *o = pair(l, h);
    }
}

/// `out[j] = pair(v[2j], v[2j + 1])`, with `v[len] = 0` for an odd length.
#[inline(always)]
fn pair_adjacent_portable(v: &[f32], out: &mut [u32]) {
    let full = v.len() / 2;
    for (o, two) in out[..full].iter_mut().zip(v.chunks_exact(2)) {
        *o = pair(two[0], two[1]);
    }
    if v.len() % 2 == 1 {
        out[full] = pair(v[v.len() - 1], 0.0);
    }
}

/// [`pair_rows_portable`] compiled for AVX-512 (16 words per step instead of 4).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl")]
fn pair_rows_avx512(lo: &[f32], hi: &[f32], out: &mut [u32]) {
    pair_rows_portable(lo, hi, out);
}

/// [`pair_adjacent_portable`] compiled for AVX-512.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl")]
fn pair_adjacent_avx512(v: &[f32], out: &mut [u32]) {
    pair_adjacent_portable(v, out);
}

/// `out[j] = pair(lo[j], hi[j])`, with AVX-512 where the CPU runs the bf16 products (the same
/// bits either way: the same integer arithmetic, wider).
fn pair_rows(lo: &[f32], hi: &[f32], out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if simd_available() {
        // SAFETY: the CPU has AVX-512F (and BW, VL: every CPU with AVX-512 BF16 has them).
        #[allow(unsafe_code)]
        unsafe {
            pair_rows_avx512(lo, hi, out);
        }
        return;
    }
    pair_rows_portable(lo, hi, out);
}

/// `out[j] = pair(v[2j], v[2j + 1])` (0 past an odd length), with AVX-512 as [`pair_rows`].
fn pair_adjacent(v: &[f32], out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if simd_available() {
        // SAFETY: as in `pair_rows`.
        #[allow(unsafe_code)]
        unsafe {
            pair_adjacent_avx512(v, out);
        }
        return;
    }
    pair_adjacent_portable(v, out);
}

// ---------------------------------------------------------------------------------------------
// Operand values.

/// An operand's values as its tensor holds them: f32, or f16 (weights held in half
/// precision), widened a run at a time while they are packed.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Values<'a> {
    /// f32 values.
    F32(&'a [f32]),
    /// f16 values.
    F16(&'a [half::f16]),
}

impl<'a> Values<'a> {
    /// Number of values.
    pub(crate) fn len(&self) -> usize {
        match self {
            Values::F32(v) => v.len(),
            Values::F16(v) => v.len(),
        }
    }

    /// Values `range` as f32: the values themselves, or f16 ones widened into `scratch`
    /// (with `half`'s vectorised slice conversion).
    fn run<'s>(&'s self, range: Range<usize>, scratch: &'s mut Vec<f32>) -> &'s [f32] {
        match self {
            Values::F32(v) => &v[range],
            Values::F16(v) => {
                scratch.resize(range.len(), 0.0);
                v[range].convert_to_f32_slice(scratch);
                scratch
            }
        }
    }

    /// Values `start..start + dst.len()` widened into `dst`.
    fn read(&self, start: usize, dst: &mut [f32]) {
        let range = start..start + dst.len();
        match self {
            Values::F32(v) => dst.copy_from_slice(&v[range]),
            Values::F16(v) => v[range].convert_to_f32_slice(dst),
        }
    }

    /// All values widened to f32 (for the bias, a few hundred values).
    fn to_f32_vec(self) -> Vec<f32> {
        let mut out = vec![0.0f32; self.len()];
        self.read(0, &mut out);
        out
    }
}

// ---------------------------------------------------------------------------------------------
// Packing.

/// Scratch space of the packing routines.
#[derive(Default)]
struct Scratch {
    values: Vec<f32>,
    rows: Vec<f32>,
    words: Vec<u32>,
}

/// Packs `lines` of a row-major `[lines, k]` matrix (line `l`'s values at `src[l·k..(l+1)·k]`)
/// over `pairs` into panels of `width` lines: word `(q·np + j)·width + t` of `dst` is
/// `pair(v[2p], v[2p + 1])` of line `lines.start + q·width + t`, `p = pairs.start + j`, with
/// `v[k] = 0` for an odd `k`; lines past `lines.end` in the last panel are zero.
///
/// Used for the operand whose lines are contiguous along `k`: the activations of a fully
/// connected layer (`A`, rows of tokens) and the weight of a convolution (`A`, `[out, in·k²]`).
/// Each line's words are made contiguously (vectorised), then transposed into the panel.
fn pack_lines(
    src: Values<'_>,
    k: usize,
    lines: Range<usize>,
    pairs: Range<usize>,
    width: usize,
    dst: &mut [u32],
    scratch: &mut Scratch,
) {
    let np = pairs.len();
    let panels = lines.len().div_ceil(width);
    assert_eq!(dst.len(), panels * np * width, "packed block length");
    let (k0, k1) = (2 * pairs.start, (2 * pairs.end).min(k));
    let Scratch { values, words, .. } = scratch;
    words.resize(width * np, 0);
    for (q, panel) in dst.chunks_exact_mut(np * width).enumerate() {
        let first = lines.start + q * width;
        let count = width.min(lines.end - first);
        for (t, line_words) in words.chunks_exact_mut(np).enumerate() {
            if t < count {
                let line = first + t;
                pair_adjacent(src.run(line * k + k0..line * k + k1, values), line_words);
            } else {
                line_words.fill(0);
            }
        }
        for (j, out) in panel.chunks_exact_mut(width).enumerate() {
            for (t, o) in out.iter_mut().enumerate() {
                *o = words[t * np + j];
            }
        }
    }
}

/// Packs `count` columns of a `[k, columns]` matrix over `pairs` into panels of `width`
/// columns, the layout of [`pack_lines`] with columns for lines; `fill(kk, row)` writes
/// entries `kk` of the `count` columns into `row`. Columns past `count` in the last panel are
/// zero.
///
/// Used for the operand whose lines are strided along `k`: the weight of a fully connected
/// layer (`B`, `[in, out]`) and the im2col columns of a convolution (`B`, built by `fill`).
fn pack_columns(
    fill: &mut dyn FnMut(usize, &mut [f32]),
    k: usize,
    count: usize,
    pairs: Range<usize>,
    width: usize,
    dst: &mut [u32],
    scratch: &mut Scratch,
) {
    let np = pairs.len();
    let panels = count.div_ceil(width);
    let padded = panels * width;
    assert_eq!(dst.len(), panels * np * width, "packed block length");
    let rows = &mut scratch.rows;
    rows.clear();
    rows.resize(2 * padded, 0.0);
    let (even, odd) = rows.split_at_mut(padded);
    for (j, p) in pairs.enumerate() {
        fill(2 * p, &mut even[..count]);
        if 2 * p + 1 < k {
            fill(2 * p + 1, &mut odd[..count]);
        } else {
            odd[..count].fill(0.0);
        }
        for (q, (lo, hi)) in even.chunks_exact(width).zip(odd.chunks_exact(width)).enumerate() {
            pair_rows(lo, hi, &mut dst[(q * np + j) * width..(q * np + j + 1) * width]);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Micro-kernels.

/// `C[0..MR, 0..NR] (+)= A·B` over `pairs` packed pairs: `a` one micro-panel of `A`
/// (`pairs·MR` words), `b` one panel of `B` (`pairs·NR` words), `c` the tile's first row, rows
/// `ldc` apart; with `accumulate` false the tile is written without being read.
///
/// # Panics
/// If a slice is shorter than the tile needs.
fn tile(simd: bool, pairs: usize, a: &[u32], b: &[u32], c: &mut [f32], ldc: usize, accumulate: bool) {
    assert!(a.len() >= pairs * MR && b.len() >= pairs * NR, "micro-panel lengths");
    assert!(ldc >= NR && c.len() >= (MR - 1) * ldc + NR, "tile out of bounds");
    #[cfg(target_arch = "x86_64")]
    if simd {
        // SAFETY: `simd` is true only where `Products::Bf16.supported()` found AVX-512F and
        // AVX-512 BF16 on this CPU; the reads and writes lie in the slices (asserted above).
        #[allow(unsafe_code)]
        unsafe {
            tile_avx512(pairs, a.as_ptr(), b.as_ptr(), c.as_mut_ptr(), ldc, accumulate);
        }
        return;
    }
    let _ = simd;
    tile_portable(pairs, a, b, c, ldc, accumulate);
}

/// [`tile`] in portable code: per pair, the high products added first, then the low ones
/// (the order Intel documents for `vdpbf16ps`), each product exact in f32.
fn tile_portable(pairs: usize, a: &[u32], b: &[u32], c: &mut [f32], ldc: usize, accumulate: bool) {
    for i in 0..MR {
        let row = &mut c[i * ldc..i * ldc + NR];
        for (j, out) in row.iter_mut().enumerate() {
            let mut sum = if accumulate { *out } else { 0.0 };
            for p in 0..pairs {
                let (x, y) = (a[p * MR + i], b[p * NR + j]);
                sum += bf16_value(x >> 16) * bf16_value(y >> 16);
                sum += bf16_value(x) * bf16_value(y);
            }
            *out = sum;
        }
    }
}

/// [`tile`] with `vdpbf16ps`: the tile in 28 registers, per pair two loads of `B` and one
/// broadcast word of `A` per row (the loop compiles to 2 loads, 14 broadcasts and 28
/// `vdpbf16ps` with no spills; alone on L1-resident data it runs at the instruction's peak).
///
/// # Safety
/// The CPU has AVX-512F and AVX-512 BF16; `a` holds `pairs·MR` words, `b` `pairs·NR` words and
/// `c` `(MR − 1)·ldc + NR` values.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn tile_avx512(pairs: usize, a: *const u32, b: *const u32, c: *mut f32, ldc: usize, accumulate: bool) {
    use std::arch::x86_64::{
        __m512, __m512bh, _mm512_dpbf16_ps, _mm512_loadu_ps, _mm512_loadu_si512, _mm512_set1_epi32, _mm512_setzero_ps,
        _mm512_storeu_ps,
    };
    // SAFETY: the caller's contract; `__m512i` and `__m512bh` are both 64 bytes of lanes, so
    // reinterpreting one as the other is a plain bit cast.
    unsafe {
        let mut acc: [[__m512; 2]; MR] = [[_mm512_setzero_ps(); 2]; MR];
        if accumulate {
            for (i, row) in acc.iter_mut().enumerate() {
                row[0] = _mm512_loadu_ps(c.add(i * ldc));
                row[1] = _mm512_loadu_ps(c.add(i * ldc + 16));
            }
        }
        for p in 0..pairs {
            let bp = b.add(p * NR);
            let b0: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.cast()));
            let b1: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.add(16).cast()));
            let ap = a.add(p * MR);
            for (i, row) in acc.iter_mut().enumerate() {
                let ai: __m512bh = std::mem::transmute(_mm512_set1_epi32(ap.add(i).read() as i32));
                row[0] = _mm512_dpbf16_ps(row[0], ai, b0);
                row[1] = _mm512_dpbf16_ps(row[1], ai, b1);
            }
        }
        for (i, row) in acc.iter().enumerate() {
            _mm512_storeu_ps(c.add(i * ldc), row[0]);
            _mm512_storeu_ps(c.add(i * ldc + 16), row[1]);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Buffers kept between products.

/// A task's buffers: its block of `C`, its packed activations, the packing's scratch space.
#[derive(Default)]
struct Buffers {
    c: Vec<f32>,
    packed: Vec<u32>,
    scratch: Scratch,
}

/// The calling thread's buffers: the packed weight, and the packed activations when all tasks
/// share them.
#[derive(Default)]
struct CallerBuffers {
    weight: Vec<u32>,
    activations: Vec<u32>,
}

thread_local! {
    /// Each worker's [`Buffers`], kept from one product to the next: fresh buffers of a few
    /// MiB would cost every task the page faults of their first writes. They hold at most a
    /// block of `C` and a block of packed activations of the largest product the thread ran
    /// (about 10 MiB at the real-size UNet's shapes).
    static BUFFERS: RefCell<Buffers> = RefCell::default();
    /// The calling thread's [`CallerBuffers`], kept for the same reason (a fresh 50 MiB
    /// buffer costs about 13 000 page faults): at most half the f32 size of the largest weight
    /// and of the largest shared im2col matrix the thread multiplied. For the real-size UNet
    /// both come from its 8×8 level's 2560 → 1280 3×3 convolutions: 56 and 34 MiB.
    static CALLER: RefCell<CallerBuffers> = RefCell::default();
}

/// Runs `f` with this thread's [`Buffers`], or fresh ones where they are in use (a task this
/// thread picked up while it waited inside another product).
fn with_buffers<R>(f: impl FnOnce(&mut Buffers) -> R) -> R {
    BUFFERS.with(|cell| match cell.try_borrow_mut() {
        Ok(mut buf) => f(&mut buf),
        Err(_) => f(&mut Buffers::default()),
    })
}

/// Runs `f` with this thread's [`CallerBuffers`], or fresh ones where they are in use.
fn with_caller_buffers<R>(f: impl FnOnce(&mut CallerBuffers) -> R) -> R {
    CALLER.with(|cell| match cell.try_borrow_mut() {
        Ok(mut buf) => f(&mut buf),
        Err(_) => f(&mut CallerBuffers::default()),
    })
}

/// `buffer` resized to `len` words, old values left (the packing writes every word).
fn sized(buffer: &mut Vec<u32>, len: usize) -> &mut [u32] {
    buffer.resize(len, 0);
    &mut buffer[..len]
}

// ---------------------------------------------------------------------------------------------
// The blocked product.

/// Which factor of `C = A·B` holds the activations (the other is the weight).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Activations {
    /// `A`: rows of tokens (a fully connected layer).
    A,
    /// `B`: im2col columns (a convolution).
    B,
}

/// Packs lines (first argument, a range starting on a panel boundary) over pairs (second)
/// into a block laid out as [`pack_lines`] describes.
type Pack<'a> = dyn Fn(Range<usize>, Range<usize>, &mut [u32], &mut Scratch) + Sync + 'a;

/// The passes over `k` a product makes: its pairs in passes of `step` (the last one shorter),
/// each at most [`KC_PAIRS`]. A packed operand of `panels` panels of `width` lines holds pass
/// `b` at word `b·step·panels·width`, and within it panel `q` at `q·np_b·width` (`np_b` the
/// pass's pairs): during a pass the micro-kernels read consecutive panels, one stream the
/// hardware prefetches, rather than panels a whole `k` apart.
#[derive(Clone, Copy, Debug)]
struct Passes {
    pairs: usize,
    step: usize,
}

impl Passes {
    fn new(k: usize) -> Self {
        let pairs = k.div_ceil(2);
        let step = pairs.div_ceil(pairs.div_ceil(KC_PAIRS).max(1)).max(1);
        Self { pairs, step }
    }

    fn count(&self) -> usize {
        self.pairs.div_ceil(self.step)
    }

    /// The pairs of pass `b`.
    fn range(&self, b: usize) -> Range<usize> {
        b * self.step..((b + 1) * self.step).min(self.pairs)
    }

    /// Word offset of panel `q` of pass `b` in an operand of `panels` panels of `width`.
    fn offset(&self, b: usize, q: usize, panels: usize, width: usize) -> usize {
        b * self.step * panels * width + q * self.range(b).len() * width
    }

    /// Packs all `lines` of an operand (panels of `width`) into `dst` in this layout with
    /// `pack`, in parallel over passes and panels.
    fn pack_all(&self, lines: usize, width: usize, dst: &mut [u32], pack: &Pack<'_>) {
        let panels = lines.div_ceil(width);
        assert_eq!(dst.len(), panels * width * self.pairs, "packed operand length");
        let per_task = panels.div_ceil(rayon::current_num_threads().max(1) * TASKS_PER_THREAD).max(1);
        dst.par_chunks_mut(self.step * panels * width).enumerate().for_each(|(b, pass)| {
            let pairs = self.range(b);
            pass.par_chunks_mut(per_task * pairs.len() * width).enumerate().for_each(|(i, dst)| {
                let first = i * per_task * width;
                let lines = first..(first + per_task * width).min(lines);
                with_buffers(|buf| pack(lines, pairs.clone(), dst, &mut buf.scratch));
            });
        });
    }
}

/// `C = A·B` with the weight's factor packed whole and the activations' packed per block.
struct Product<'a> {
    /// The passes over `k`, the length of the products' sums (`A`'s columns, `B`'s rows).
    passes: Passes,
    /// Activation lines: `A`'s rows or `B`'s columns.
    act_lines: usize,
    /// Weight lines: `B`'s columns or `A`'s rows.
    wt_lines: usize,
    /// The weight packed over all pairs in the [`Passes`] layout: panels of [`NR`] columns when
    /// the activations are `A`, micro-panels of [`MR`] rows when they are `B`.
    weight: &'a [u32],
    activations: Activations,
    /// Packs activation lines over pairs.
    gather: &'a Pack<'a>,
    /// Whether the AVX-512 BF16 micro-kernel runs (else the portable one).
    simd: bool,
}

impl Product<'_> {
    /// Panel widths: (activation lines, weight lines).
    fn widths(&self) -> (usize, usize) {
        match self.activations {
            Activations::A => (MR, NR),
            Activations::B => (NR, MR),
        }
    }

    /// The block of `C` of activation lines `act` and weight lines `wt` (both starting on a
    /// panel boundary) into `buf.c`, row-major in `C`'s orientation, padded to whole panels;
    /// returns its row stride. The activations come packed, all of them, in `shared`, or are
    /// packed here (the block's lines only). `k` must be positive.
    fn block(&self, act: Range<usize>, wt: Range<usize>, shared: Option<&[u32]>, buf: &mut Buffers) -> usize {
        let (aw, ww) = self.widths();
        debug_assert!(act.start.is_multiple_of(aw) && wt.start.is_multiple_of(ww));
        let passes = self.passes;
        let (act_panels, wt_panels) = (act.len().div_ceil(aw), wt.len().div_ceil(ww));
        let (rows, cols) = match self.activations {
            Activations::A => (act_panels * MR, wt_panels * NR),
            Activations::B => (wt_panels * MR, act_panels * NR),
        };
        let Buffers { c, packed, scratch } = buf;
        // Every value is written by the first pass over `k` (no accumulation), so the buffer's
        // old values need no clearing.
        c.resize(rows * cols, 0.0);
        // Where the activations are: (all of them, in panels; this block's first panel).
        let (packed, act_all_panels, act_first): (&[u32], usize, usize) = match shared {
            Some(all) => (all, self.act_lines.div_ceil(aw), act.start / aw),
            None => {
                let block = sized(packed, act_panels * aw * passes.pairs);
                for b in 0..passes.count() {
                    let dst =
                        &mut block[passes.offset(b, 0, act_panels, aw)..][..act_panels * aw * passes.range(b).len()];
                    (self.gather)(act.clone(), passes.range(b), dst, scratch);
                }
                (block, act_panels, 0)
            }
        };
        let wt_all_panels = self.wt_lines.div_ceil(ww);
        // A group of weight panels at a time (its part of the block of `C` in the second-level
        // cache), every pass over `k`; within a pass, each panel of `B` (16 KiB) stays in the
        // first-level cache while the micro-panels of `A` (7 KiB each) stream past it.
        let group = (C_GROUP_BYTES / (4 * ww * act_panels * aw)).clamp(1, wt_panels);
        for g0 in (0..wt_panels).step_by(group) {
            let group = g0..(g0 + group).min(wt_panels);
            for b in 0..passes.count() {
                let np = passes.range(b).len();
                let w0 = passes.offset(b, wt.start / ww, wt_all_panels, ww);
                let a0 = passes.offset(b, act_first, act_all_panels, aw);
                let weight = |wq: usize| &self.weight[w0 + wq * np * ww..][..np * ww];
                let act = |aq: usize| &packed[a0 + aq * np * aw..][..np * aw];
                let (b_panels, a_panels) = match self.activations {
                    Activations::A => (group.clone(), 0..act_panels),
                    Activations::B => (0..act_panels, group.clone()),
                };
                for bq in b_panels {
                    for aq in a_panels.clone() {
                        let (a, b_panel, row, col) = match self.activations {
                            Activations::A => (act(aq), weight(bq), aq * MR, bq * NR),
                            Activations::B => (weight(aq), act(bq), aq * MR, bq * NR),
                        };
                        tile(self.simd, np, a, b_panel, &mut c[row * cols + col..], cols, b > 0);
                    }
                }
            }
        }
        cols
    }

    /// Runs `tasks` on rayon's pool, each copying its block of `C` into its segments. Where an
    /// activation block serves several tasks (`shared`), all activations are packed first, once,
    /// into `activations`.
    fn run(&self, tasks: Vec<Task<'_>>, shared: bool, activations: &mut Vec<u32>) {
        if !shared {
            tasks.into_par_iter().for_each(|task| with_buffers(|buf| self.copy_out(task, None, buf)));
            return;
        }
        let (aw, _) = self.widths();
        let all = sized(activations, self.act_lines.div_ceil(aw) * aw * self.passes.pairs);
        self.passes.pack_all(self.act_lines, aw, all, self.gather);
        let all: &[u32] = all;
        tasks.into_par_iter().for_each(|task| with_buffers(|buf| self.copy_out(task, Some(all), buf)));
    }

    /// Computes `task`'s block of `C` and copies it into the task's segments, adding the bias.
    fn copy_out(&self, task: Task<'_>, shared: Option<&[u32]>, buf: &mut Buffers) {
        let ldc = self.block(task.act, task.wt, shared, buf);
        for s in task.segments {
            let src = &buf.c[s.row * ldc + s.col..][..s.out.len()];
            match s.bias {
                SegmentBias::None => s.out.copy_from_slice(src),
                SegmentBias::All(b) => s.out.iter_mut().zip(src).for_each(|(o, &v)| *o = v + b),
                SegmentBias::Each(b) => {
                    s.out.iter_mut().zip(src).zip(b).for_each(|((o, &v), &b)| *o = v + b);
                }
            }
        }
    }
}

/// What a segment of the output adds to its values of `C`.
enum SegmentBias<'a> {
    None,
    /// One bias for the whole segment (a convolution's output channel).
    All(f32),
    /// One per value (a fully connected layer's output features).
    Each(&'a [f32]),
}

/// A run of output values a task writes: `C`-block entries `(row, col..col + len)`.
struct Segment<'o> {
    row: usize,
    col: usize,
    out: &'o mut [f32],
    bias: SegmentBias<'o>,
}

/// One parallel task: activation lines `act`, weight lines `wt`, and the output it owns.
struct Task<'o> {
    act: Range<usize>,
    wt: Range<usize>,
    segments: Vec<Segment<'o>>,
}

/// How a product's work is split: blocks of activation lines and ranges of weight lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Plan {
    act_block: usize,
    wt_block: usize,
}

impl Plan {
    /// The split of `act` activation lines in panels of `aw` and `wt` weight lines in panels of
    /// `ww`: activation blocks as wide as [`MAX_BLOCK_PANELS`] allows, evenly sized; weight
    /// lines split only when the activation blocks are fewer than [`TASKS_PER_THREAD`] per
    /// thread, into a number of ranges that makes the task count a multiple of the thread count
    /// where the panels allow.
    fn new(act: usize, aw: usize, wt: usize, ww: usize) -> Self {
        let threads = rayon::current_num_threads().max(1);
        let target = threads * TASKS_PER_THREAD;
        let act_panels = act.div_ceil(aw).max(1);
        let act_block = act_panels.div_ceil(act_panels.div_ceil(MAX_BLOCK_PANELS)) * aw;
        let act_blocks = act.div_ceil(act_block).max(1);
        let wt_panels = wt.div_ceil(ww).max(1);
        let mut wt_blocks = 1;
        if act_blocks < target {
            wt_blocks = target.div_ceil(act_blocks).min(wt_panels);
            while wt_blocks < wt_panels && !(act_blocks * wt_blocks).is_multiple_of(threads) {
                wt_blocks += 1;
            }
        }
        Plan { act_block, wt_block: wt_panels.div_ceil(wt_blocks) * ww }
    }

    /// Whether an activation block serves several tasks (the weight lines are split).
    fn shared(&self, wt: usize) -> bool {
        wt > self.wt_block
    }

    /// The empty tasks of `act × wt` lines, activation block-major.
    fn tasks<'o>(&self, act: usize, wt: usize) -> Vec<Task<'o>> {
        let (act_blocks, wt_blocks) = (act.div_ceil(self.act_block), wt.div_ceil(self.wt_block));
        (0..act_blocks * wt_blocks)
            .map(|t| {
                let (ai, wi) = (t / wt_blocks, t % wt_blocks);
                Task {
                    act: ai * self.act_block..((ai + 1) * self.act_block).min(act),
                    wt: wi * self.wt_block..((wi + 1) * self.wt_block).min(wt),
                    segments: Vec::new(),
                }
            })
            .collect()
    }
}

/// Whether this CPU runs the AVX-512 BF16 micro-kernel.
fn simd_available() -> bool {
    Products::Bf16.supported()
}

// ---------------------------------------------------------------------------------------------
// The layers' products on slices.

/// A fully connected layer `x·W + b` with bf16 products: `x` `[rows, d_in]`, `weight`
/// `[d_in, d_out]` (the layout [`crate::nn::Linear`] holds), `bias` `[d_out]`; returns
/// `[rows, d_out]`, all row-major. Records `rows·d_in·d_out` bf16 multiply-adds on the calling
/// thread.
///
/// # Panics
/// If a length does not match the shape.
pub(crate) fn linear(
    x: &[f32],
    weight: Values<'_>,
    bias: Option<&[f32]>,
    rows: usize,
    d_in: usize,
    d_out: usize,
) -> Vec<f32> {
    linear_with(x, weight, bias, [rows, d_in, d_out], simd_available())
}

/// [`linear`] with the micro-kernel chosen by `simd` (the tests run both).
pub(crate) fn linear_with(
    x: &[f32],
    weight: Values<'_>,
    bias: Option<&[f32]>,
    [rows, d_in, d_out]: [usize; 3],
    simd: bool,
) -> Vec<f32> {
    assert_eq!(x.len(), rows * d_in, "input length");
    assert_eq!(weight.len(), d_in * d_out, "weight length");
    if let Some(b) = bias {
        assert_eq!(b.len(), d_out, "bias length");
    }
    compute::record(WorkKind::Bf16MultiplyAdds, (rows * d_in * d_out) as u64);
    let mut out = vec![0.0f32; rows * d_out];
    if out.is_empty() {
        return out;
    }
    if d_in == 0 {
        if let Some(b) = bias {
            out.chunks_exact_mut(d_out).for_each(|row| row.copy_from_slice(b));
        }
        return out;
    }
    let passes = Passes::new(d_in);
    with_caller_buffers(|caller| {
        // The weight (`B`, `[d_in, d_out]`) in panels of NR columns.
        let packed = sized(&mut caller.weight, d_out.div_ceil(NR) * NR * passes.pairs);
        let pack_weight = |columns: Range<usize>, pairs: Range<usize>, dst: &mut [u32], scratch: &mut Scratch| {
            let c0 = columns.start;
            let mut fill = |kk: usize, row: &mut [f32]| weight.read(kk * d_out + c0, row);
            pack_columns(&mut fill, d_in, columns.len(), pairs, NR, dst, scratch);
        };
        passes.pack_all(d_out, NR, packed, &pack_weight);
        let gather = |lines: Range<usize>, pairs: Range<usize>, dst: &mut [u32], scratch: &mut Scratch| {
            pack_lines(Values::F32(x), d_in, lines, pairs, MR, dst, scratch);
        };
        let product = Product {
            passes,
            act_lines: rows,
            wt_lines: d_out,
            weight: packed,
            activations: Activations::A,
            gather: &gather,
            simd,
        };
        let plan = Plan::new(rows, MR, d_out, NR);
        let mut tasks = plan.tasks(rows, d_out);
        let wt_blocks = d_out.div_ceil(plan.wt_block);
        for (r, mut row) in out.chunks_mut(d_out).enumerate() {
            let ai = r / plan.act_block;
            for wi in 0..wt_blocks {
                let j0 = wi * plan.wt_block;
                let (segment, rest) = std::mem::take(&mut row).split_at_mut(plan.wt_block.min(d_out - j0));
                row = rest;
                let bias = bias.map_or(SegmentBias::None, |b| SegmentBias::Each(&b[j0..j0 + segment.len()]));
                let segment = Segment { row: r - ai * plan.act_block, col: 0, out: segment, bias };
                tasks[ai * wt_blocks + wi].segments.push(segment);
            }
        }
        product.run(tasks, plan.shared(d_out), &mut caller.activations);
    });
    out
}

/// A 2-D convolution (im2col + one product, the column matrix built block by block) with bf16
/// products: `x` `[batch, c_in, h, w]`, `weight` `[c_out, c_in, k, k]`, `bias` `[c_out]`;
/// returns `[batch, c_out, h_out, w_out]`. Records `c_out·c_in·k²·batch·h_out·w_out` bf16
/// multiply-adds on the calling thread.
///
/// # Panics
/// If a length does not match `g` or the kernel does not fit the padded image.
pub(crate) fn conv2d(x: &[f32], weight: Values<'_>, bias: Option<&[f32]>, g: ConvShape) -> Vec<f32> {
    conv2d_with(x, weight, bias, g, simd_available())
}

/// [`conv2d`] with the micro-kernel chosen by `simd` (the tests run both).
pub(crate) fn conv2d_with(x: &[f32], weight: Values<'_>, bias: Option<&[f32]>, g: ConvShape, simd: bool) -> Vec<f32> {
    let (ho, wo) = g.output().expect("a kernel that fits the padded image");
    let (m, k, pixels) = (g.c_out, g.c_in * g.kernel * g.kernel, ho * wo);
    let n = g.batch * pixels;
    assert_eq!(x.len(), g.batch * g.c_in * g.height * g.width, "input length");
    assert_eq!(weight.len(), m * k, "weight length");
    if let Some(b) = bias {
        assert_eq!(b.len(), m, "bias length");
    }
    compute::record(WorkKind::Bf16MultiplyAdds, (m * n * k) as u64);
    let mut out = vec![0.0f32; m * n];
    if out.is_empty() {
        return out;
    }
    if k == 0 {
        if let Some(b) = bias {
            for (plane, &b) in out.chunks_exact_mut(pixels).zip(b.iter().cycle()) {
                plane.fill(b);
            }
        }
        return out;
    }
    let passes = Passes::new(k);
    with_caller_buffers(|caller| {
        // The weight (`A`, `[c_out, c_in·k²]`) in micro-panels of MR rows.
        let packed = sized(&mut caller.weight, m.div_ceil(MR) * MR * passes.pairs);
        let pack_weight = |lines: Range<usize>, pairs: Range<usize>, dst: &mut [u32], scratch: &mut Scratch| {
            pack_lines(weight, k, lines, pairs, MR, dst, scratch);
        };
        passes.pack_all(m, MR, packed, &pack_weight);
        let gather = |columns: Range<usize>, pairs: Range<usize>, dst: &mut [u32], scratch: &mut Scratch| {
            let runs = ColumnRuns::new(columns.clone(), g);
            let mut fill = |kk: usize, row: &mut [f32]| runs.im2col_row(x, kk, row);
            pack_columns(&mut fill, k, columns.len(), pairs, NR, dst, scratch);
        };
        let product = Product {
            passes,
            act_lines: n,
            wt_lines: m,
            weight: packed,
            activations: Activations::B,
            gather: &gather,
            simd,
        };
        let plan = Plan::new(n, NR, m, MR);
        let mut tasks = plan.tasks(n, m);
        let wt_blocks = m.div_ceil(plan.wt_block);
        for (image, planes) in out.chunks_mut(m * pixels).enumerate() {
            for (o, mut plane) in planes.chunks_mut(pixels).enumerate() {
                let wi = o / plan.wt_block;
                let (mut col, end) = (image * pixels, (image + 1) * pixels);
                while col < end {
                    let ai = col / plan.act_block;
                    let stop = ((ai + 1) * plan.act_block).min(end);
                    let (segment, rest) = std::mem::take(&mut plane).split_at_mut(stop - col);
                    plane = rest;
                    let bias = bias.map_or(SegmentBias::None, |b| SegmentBias::All(b[o]));
                    let (row, col_in_block) = (o - wi * plan.wt_block, col - ai * plan.act_block);
                    let segment = Segment { row, col: col_in_block, out: segment, bias };
                    tasks[ai * wt_blocks + wi].segments.push(segment);
                    col = stop;
                }
            }
        }
        product.run(tasks, plan.shared(m), &mut caller.activations);
    });
    out
}

/// A block of im2col columns (output pixels of all images, image-major) as the runs it is
/// made of: whole images' pixel ranges for a same-size convolution
/// ([`ConvShape::same_size`]), runs within one output row otherwise.
struct ColumnRuns {
    g: ConvShape,
    /// `(offset in the block, image, first output pixel, length)`.
    runs: Vec<(usize, usize, usize, usize)>,
}

impl ColumnRuns {
    fn new(columns: Range<usize>, g: ConvShape) -> Self {
        let (ho, wo) = g.output().expect("checked by conv2d_with");
        let pixels = ho * wo;
        let mut runs = Vec::new();
        let mut col = columns.start;
        while col < columns.end {
            let (image, pixel) = (col / pixels, col % pixels);
            // Same size: to the end of the image; else to the end of the output row.
            let end_of_run = if g.same_size() { pixels } else { (pixel / wo + 1) * wo };
            let len = (end_of_run - pixel).min(columns.end - col);
            runs.push((col - columns.start, image, pixel, len));
            col += len;
        }
        Self { g, runs }
    }

    /// Row `kk = (c·k + ky)·k + kx` of the im2col matrix over the block's columns: the input
    /// value kernel tap `(ky, kx)` of channel `c` reads for each output pixel, 0 in the
    /// padding.
    fn im2col_row(&self, x: &[f32], kk: usize, row: &mut [f32]) {
        let g = self.g;
        let (kernel, s, p, h, w) = (g.kernel, g.stride, g.padding, g.height, g.width);
        let (c, ky, kx) = (kk / (kernel * kernel), kk / kernel % kernel, kk % kernel);
        let (_, wo) = g.output().expect("checked by conv2d_with");
        if g.same_size() {
            // The plane shifted by (ky − p) rows and (kx − p) columns: one copy per image, the
            // pixels whose tap falls above or below the image cleared around it, then those
            // whose horizontal shift wrapped to the neighbouring row.
            let pixels = h * w;
            let (dy, dx) = (ky as isize - p as isize, kx as isize - p as isize);
            let shift = dy * w as isize + dx;
            for &(offset, image, first, len) in &self.runs {
                let plane = &x[(image * g.c_in + c) * pixels..][..pixels];
                let dst = &mut row[offset..offset + len];
                let lo = (-shift).clamp(first as isize, (first + len) as isize) as usize;
                let hi = (pixels as isize - shift).clamp(lo as isize, (first + len) as isize) as usize;
                dst[..lo - first].fill(0.0);
                dst[hi - first..].fill(0.0);
                if hi > lo {
                    let src = (lo as isize + shift) as usize;
                    dst[lo - first..hi - first].copy_from_slice(&plane[src..src + (hi - lo)]);
                }
                if dx != 0 {
                    let edge = dx.unsigned_abs().min(w);
                    // Output columns 0..edge (dx < 0) or w − edge..w (dx > 0) of each row.
                    let skip = if dx < 0 { 0 } else { w - edge };
                    let mut oy0 = first / w;
                    while oy0 * w < first + len {
                        let a = (oy0 * w + skip).max(first);
                        let b = (oy0 * w + skip + edge).min(first + len);
                        if a < b {
                            dst[a - first..b - first].fill(0.0);
                        }
                        oy0 += 1;
                    }
                }
            }
            return;
        }
        // Output columns whose tap lies inside the image: ox·s + kx − p in 0..w.
        let first_inside = p.saturating_sub(kx).div_ceil(s);
        let end_inside = (w + p).saturating_sub(kx).div_ceil(s);
        for &(offset, image, first, len) in &self.runs {
            let (oy, ox0) = (first / wo, first % wo);
            let dst = &mut row[offset..offset + len];
            let Some(iy) = (oy * s + ky).checked_sub(p).filter(|&iy| iy < h) else {
                dst.fill(0.0);
                continue;
            };
            let line = &x[((image * g.c_in + c) * h + iy) * w..][..w];
            let run_end = ox0 + len;
            let lo = first_inside.clamp(ox0, run_end);
            let hi = end_inside.clamp(lo, run_end);
            dst[..lo - ox0].fill(0.0);
            dst[hi - ox0..].fill(0.0);
            if hi > lo {
                let inside = &mut dst[lo - ox0..hi - ox0];
                let ix0 = lo * s + kx - p;
                if s == 1 {
                    inside.copy_from_slice(&line[ix0..ix0 + inside.len()]);
                } else {
                    for (v, &value) in inside.iter_mut().zip(line[ix0..].iter().step_by(s)) {
                        *v = value;
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Tensor glue.

/// Whether a product with activations `x` and `weight` runs in bf16: the pass asks for bf16
/// products ([`compute::settings`]), the CPU has the instructions, `x` is an f32 tensor on a
/// CPU backend with no autodiff graph, and the weight is f32 or f16 there too.
pub(crate) fn applies<const D: usize, const E: usize>(x: &Tensor<D>, weight: &Tensor<E>) -> bool {
    compute::settings().products == Products::Bf16
        && Products::Bf16.supported()
        && cpu_inference_f32(x)
        && matches!(weight.dtype(), DType::F32 | DType::F16)
        && !weight.is_autodiff()
        && on_cpu_backend(&weight.device())
}

/// Runs `f` on the values of `t` (f32 or f16): on flex the tensor's own memory when it is
/// contiguous, else a copy.
fn with_values<const D: usize, R>(t: Tensor<D>, f: impl FnOnce(Values<'_>) -> R) -> R {
    if let Ok(flex) = t.clone().try_into_primitive::<Flex>() {
        if let Some(v) = flex.as_slice::<f32>() {
            return f(Values::F32(v));
        }
        if let Some(v) = flex.as_slice::<half::f16>() {
            return f(Values::F16(v));
        }
    }
    let dtype = t.dtype();
    let data = t.into_data();
    match dtype {
        DType::F16 => f(Values::F16(data.as_slice::<half::f16>().expect("f16 values"))),
        _ => {
            let v = data.convert::<f32>();
            f(Values::F32(v.as_slice::<f32>().expect("f32 values")))
        }
    }
}

/// [`linear`] on tensors: `x` `[rows, d_in]`, `weight` `[d_in, d_out]`, `bias` `[d_out]`
/// (as [`applies`] accepted them).
pub(crate) fn linear_tensor(x: Tensor<2>, weight: Tensor<2>, bias: Option<Tensor<1>>) -> Tensor<2> {
    let device = x.device();
    let [rows, d_in] = x.dims();
    let [w_in, d_out] = weight.dims();
    assert_eq!(d_in, w_in, "linear: input features");
    let bias = bias.map(|b| with_values(b, |v| v.to_f32_vec()));
    let out = with_values(x, |x| {
        let Values::F32(x) = x else { unreachable!("f32 activations (checked by applies)") };
        with_values(weight, |w| linear(x, w, bias.as_deref(), rows, d_in, d_out))
    });
    Tensor::from_data(TensorData::new(out, [rows, d_out]), &device)
}

/// The geometry of a convolution of `x` (`[n, c, h, w]`) with `weight` (`[o, c, k, k]`);
/// `None` where the shapes do not make one (the caller's f32 path then reports it).
pub(crate) fn conv_geometry(x: &Tensor<4>, weight: &Tensor<4>, stride: usize, padding: usize) -> Option<ConvShape> {
    let [batch, c_in, height, width] = x.dims();
    let [c_out, w_in, kernel, kernel_w] = weight.dims();
    let g = ConvShape { batch, c_in, height, width, c_out, kernel, stride, padding };
    (w_in == c_in && kernel == kernel_w && g.output().is_some()).then_some(g)
}

/// [`conv2d`] on tensors: `x` `[n, c, h, w]`, `weight` `[o, c, k, k]`, `bias` `[o]` (as
/// [`applies`] and [`conv_geometry`] accepted them).
pub(crate) fn conv2d_tensor(x: Tensor<4>, weight: Tensor<4>, bias: Option<Tensor<1>>, g: ConvShape) -> Tensor<4> {
    let (ho, wo) = g.output().expect("checked by conv_geometry");
    let device = x.device();
    let bias = bias.map(|b| with_values(b, |v| v.to_f32_vec()));
    let out = with_values(x, |x| {
        let Values::F32(x) = x else { unreachable!("f32 activations (checked by applies)") };
        with_values(weight, |w| conv2d(x, w, bias.as_deref(), g))
    });
    Tensor::from_data(TensorData::new(out, [g.batch, g.c_out, ho, wo]), &device)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in about [-1, 1] (a small LCG), with some exact zeros.
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let u = (s >> 40) as f32 / (1u64 << 24) as f32;
                if u < 0.02 { 0.0 } else { 2.0 * u - 1.0 }
            })
            .collect()
    }

    /// `x·W + b` in f64 from the bf16-rounded factors, and per output the sum of the
    /// products' magnitudes (the scale of the f32 summation's rounding).
    fn reference(x: &[f32], w: &[f32], bias: Option<&[f32]>, [m, k, n]: [usize; 3]) -> (Vec<f64>, Vec<f64>) {
        let mut out = vec![0.0f64; m * n];
        let mut scale = vec![0.0f64; m * n];
        for i in 0..m {
            for j in 0..n {
                let (mut s, mut a) = (0.0f64, 0.0f64);
                for kk in 0..k {
                    let p = round_bf16(x[i * k + kk]) as f64 * round_bf16(w[kk * n + j]) as f64;
                    s += p;
                    a += p.abs();
                }
                out[i * n + j] = s + bias.map_or(0.0, |b| b[j] as f64);
                scale[i * n + j] = a;
            }
        }
        (out, scale)
    }

    /// The kernels this CPU can run: the portable one, and the AVX-512 BF16 one where present.
    fn kernels() -> Vec<bool> {
        if simd_available() { vec![false, true] } else { vec![false] }
    }

    #[test]
    fn rounding_is_to_nearest_even_and_keeps_nan() {
        assert_eq!(bf16_bits(1.0), 0x3f80);
        // 1 + 2⁻⁸ is halfway between 1 and 1 + 2⁻⁷: ties to the even 1.
        assert_eq!(bf16_bits(1.0 + 1.0 / 256.0), 0x3f80);
        // 1 + 3·2⁻⁸ is halfway between 1 + 2⁻⁷ and 1 + 2⁻⁶: ties to the even 1 + 2⁻⁶.
        assert_eq!(bf16_bits(1.0 + 3.0 / 256.0), 0x3f82);
        assert_eq!(bf16_bits(1.0 + 1.5 / 256.0), 0x3f81);
        assert_eq!(bf16_bits(-2.5), 0xc020);
        assert_eq!(bf16_value(bf16_bits(f32::INFINITY)), f32::INFINITY);
        assert_eq!(bf16_value(bf16_bits(f32::MAX)), f32::INFINITY);
        assert!(bf16_value(bf16_bits(f32::NAN)).is_nan());
        // A NaN whose payload sits in the low bits only would round to infinity without care.
        assert!(bf16_value(bf16_bits(f32::from_bits(0x7f80_0001))).is_nan());
        assert!(bf16_value(bf16_bits(f32::from_bits(0xff80_0001))).is_nan());
        for x in values(1000, 3) {
            let r = round_bf16(x);
            assert!((r - x).abs() <= x.abs() / 256.0, "{x} rounded to {r}");
            assert_eq!(r, half::bf16::from_f32(x).to_f32(), "{x}");
        }
    }

    #[test]
    fn linear_matches_the_f64_reference_of_the_rounded_factors() {
        let shapes = [
            [1, 1, 1],
            [1, 2, 33],
            [17, 33, 1],
            [15, 17, 31],
            [29, 513, 65],
            [33, 260, 96],
            [250, 64, 40],
            [3, 1031, 17],
        ];
        for simd in kernels() {
            for (s, &[m, k, n]) in shapes.iter().enumerate() {
                let x = values(m * k, 10 + s as u64);
                let w = values(k * n, 20 + s as u64);
                let bias = values(n, 30 + s as u64);
                let (want, scale) = reference(&x, &w, Some(&bias), [m, k, n]);
                let got = linear_with(&x, Values::F32(&w), Some(&bias), [m, k, n], simd);
                for (i, ((&g, &r), &a)) in got.iter().zip(&want).zip(&scale).enumerate() {
                    let err = (g as f64 - r).abs();
                    assert!(err <= 1e-5 * a + 1e-6, "simd {simd}, {m}×{k}×{n}, entry {i}: {g} vs {r} (scale {a})");
                }
                // The f16 weight gives the products of its f32 values.
                let w16: Vec<half::f16> = w.iter().map(|&v| half::f16::from_f32(v)).collect();
                let w16_wide: Vec<f32> = w16.iter().map(|v| v.to_f32()).collect();
                let a = linear_with(&x, Values::F16(&w16), Some(&bias), [m, k, n], simd);
                let b = linear_with(&x, Values::F32(&w16_wide), Some(&bias), [m, k, n], simd);
                assert_eq!(a, b, "f16 weight, {m}×{k}×{n}");
            }
        }
    }

    #[test]
    fn linear_stays_within_bf16_rounding_of_f32() {
        // Against the f32 product of the unrounded factors: each factor moves by at most 2⁻⁹
        // relative, so each product by at most about 2⁻⁸ = 3.9e-3; the worst error relative to
        // the sum of the products' magnitudes measured 3.8e-4 here (the roundings' signs
        // cancel most of it). Bound: twice that.
        let [m, k, n] = [37, 700, 45];
        let (x, w) = (values(m * k, 1), values(k * n, 2));
        let got = linear_with(&x, Values::F32(&w), None, [m, k, n], simd_available());
        let mut worst = 0.0f64;
        for i in 0..m {
            for j in 0..n {
                let (mut s, mut a) = (0.0f64, 0.0f64);
                for kk in 0..k {
                    let p = x[i * k + kk] as f64 * w[kk * n + j] as f64;
                    s += p;
                    a += p.abs();
                }
                worst = worst.max((got[i * n + j] as f64 - s).abs() / a);
            }
        }
        eprintln!("linear {m}×{k}×{n}: bf16 vs exact, worst error / Σ|products| = {worst:.2e}");
        assert!(worst > 0.0 && worst <= 8e-4, "{worst}");
    }

    #[test]
    fn nan_and_infinity_propagate() {
        let [m, k, n] = [15, 5, 33];
        let mut x = values(m * k, 4);
        x[3 * k + 2] = f32::NAN;
        x[7 * k + 4] = f32::INFINITY;
        let w = values(k * n, 5);
        for simd in kernels() {
            let y = linear_with(&x, Values::F32(&w), None, [m, k, n], simd);
            assert!(y[3 * n..4 * n].iter().all(|v| v.is_nan()), "simd {simd}");
            assert!(y[7 * n..8 * n].iter().all(|v| !v.is_finite()), "simd {simd}");
            assert!(y[..3 * n].iter().all(|v| v.is_finite()), "simd {simd}");
        }
    }

    /// The convolution by loops over the bf16-rounded factors, in f64, with the sums of the
    /// products' magnitudes.
    fn conv_reference(x: &[f32], w: &[f32], bias: &[f32], g: ConvShape) -> (Vec<f64>, Vec<f64>) {
        let (ho, wo) = g.output().unwrap();
        let (k, s, p) = (g.kernel, g.stride, g.padding);
        let mut out = vec![0.0; g.batch * g.c_out * ho * wo];
        let mut scale = out.clone();
        for b in 0..g.batch {
            for o in 0..g.c_out {
                for oy in 0..ho {
                    for ox in 0..wo {
                        let (mut sum, mut a) = (0.0f64, 0.0f64);
                        for c in 0..g.c_in {
                            for ky in 0..k {
                                for kx in 0..k {
                                    let (iy, ix) =
                                        ((oy * s + ky) as isize - p as isize, (ox * s + kx) as isize - p as isize);
                                    if iy < 0 || ix < 0 || iy >= g.height as isize || ix >= g.width as isize {
                                        continue;
                                    }
                                    let xv = x[((b * g.c_in + c) * g.height + iy as usize) * g.width + ix as usize];
                                    let wv = w[((o * g.c_in + c) * k + ky) * k + kx];
                                    let prod = round_bf16(xv) as f64 * round_bf16(wv) as f64;
                                    sum += prod;
                                    a += prod.abs();
                                }
                            }
                        }
                        let i = ((b * g.c_out + o) * ho + oy) * wo + ox;
                        out[i] = sum + bias[o] as f64;
                        scale[i] = a;
                    }
                }
            }
        }
        (out, scale)
    }

    #[test]
    fn conv2d_matches_the_f64_reference_of_the_rounded_factors() {
        let shapes = [
            // batch, c_in, h, w, c_out, kernel, stride, padding
            [1, 1, 1, 1, 1, 1, 1, 0],
            [2, 3, 5, 7, 4, 3, 1, 1],
            [3, 8, 4, 4, 17, 3, 1, 1],
            [2, 5, 9, 6, 15, 3, 2, 1],
            [1, 33, 8, 8, 29, 1, 1, 0],
            [5, 6, 6, 5, 7, 3, 1, 0],
            [2, 40, 12, 12, 16, 3, 1, 1],
            [1, 2, 3, 3, 3, 5, 1, 2],
            // Blocks of 256 pixels that end inside image rows of 40.
            [1, 3, 40, 40, 5, 3, 1, 1],
            // Shared activations packed in blocks that end a few pixels before an image's end
            // (runs whose taps all fall below the image).
            [2, 9, 7, 7, 17, 3, 1, 1],
            [3, 4, 5, 5, 40, 3, 1, 1],
        ];
        for simd in kernels() {
            for (s, &[batch, c_in, height, width, c_out, kernel, stride, padding]) in shapes.iter().enumerate() {
                let g = ConvShape { batch, c_in, height, width, c_out, kernel, stride, padding };
                let x = values(batch * c_in * height * width, 40 + s as u64);
                let w = values(c_out * c_in * kernel * kernel, 50 + s as u64);
                let bias = values(c_out, 60 + s as u64);
                let (want, scale) = conv_reference(&x, &w, &bias, g);
                let got = conv2d_with(&x, Values::F32(&w), Some(&bias), g, simd);
                assert_eq!(got.len(), want.len());
                for (i, ((&v, &r), &a)) in got.iter().zip(&want).zip(&scale).enumerate() {
                    let err = (v as f64 - r).abs();
                    assert!(err <= 1e-5 * a + 1e-6, "simd {simd}, {g:?}, entry {i}: {v} vs {r} (scale {a})");
                }
            }
        }
    }

    #[test]
    fn random_convolutions_match_the_reference() {
        // 60 geometries drawn from a fixed seed: kernels 1–5, strides 1–3, paddings 0–3, images
        // of 1–12 pixels a side, so that blocks and runs end anywhere in images and rows.
        let mut state = 0x1234_5678_9abc_def0u64;
        let mut draw = |n: usize| {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as usize % n
        };
        let mut tried = 0;
        while tried < 60 {
            let (kernel, stride, padding) = (1 + draw(5), 1 + draw(3), draw(4));
            let (height, width) = (1 + draw(12), 1 + draw(12));
            let (batch, c_in, c_out) = (1 + draw(3), 1 + draw(6), 1 + draw(33));
            let g = ConvShape { batch, c_in, height, width, c_out, kernel, stride, padding };
            if g.output().is_none() {
                continue;
            }
            tried += 1;
            let x = values(batch * c_in * height * width, tried as u64);
            let w = values(c_out * c_in * kernel * kernel, 100 + tried as u64);
            let bias = values(c_out, 200 + tried as u64);
            let (want, scale) = conv_reference(&x, &w, &bias, g);
            let got = conv2d_with(&x, Values::F32(&w), Some(&bias), g, simd_available());
            for (i, ((&v, &r), &a)) in got.iter().zip(&want).zip(&scale).enumerate() {
                assert!((v as f64 - r).abs() <= 1e-5 * a + 1e-6, "{g:?}, entry {i}: {v} vs {r}");
            }
        }
    }

    #[test]
    fn work_splits_cover_every_line() {
        for &(act, aw, wt, ww) in &[(1, MR, 1, NR), (768, MR, 1280, NR), (192, NR, 1280, MR), (12288, NR, 320, MR)] {
            let plan = Plan::new(act, aw, wt, ww);
            assert!(plan.act_block.is_multiple_of(aw) && plan.wt_block.is_multiple_of(ww));
            assert!(plan.act_block <= MAX_BLOCK_PANELS * aw);
            let covered: usize = plan.tasks(act, wt).iter().map(|t| t.act.len() * t.wt.len()).sum();
            assert_eq!(covered, act * wt);
        }
    }

    #[test]
    fn vectorised_pairing_gives_the_portable_bits() {
        let mut v = values(1001, 9);
        v.extend([f32::NAN, -f32::NAN, f32::INFINITY, f32::MAX, 1.0 + 1.0 / 256.0, 1.0e-40, -0.0, -3.0]);
        let (lo, hi) = v.split_at(v.len() / 2);
        let mut fast = vec![0u32; lo.len()];
        let mut slow = fast.clone();
        pair_rows(lo, &hi[..lo.len()], &mut fast);
        pair_rows_portable(lo, &hi[..lo.len()], &mut slow);
        assert_eq!(fast, slow);
        let mut fast = vec![0u32; v.len().div_ceil(2)];
        let mut slow = fast.clone();
        pair_adjacent(&v, &mut fast);
        pair_adjacent_portable(&v, &mut slow);
        assert_eq!(fast, slow);
        assert_eq!(slow[slow.len() - 1] >> 16, 0, "an odd length pads with 0");
    }

    /// The micro-kernel's rate inside [`Product::block`] on one thread, synthetic operands
    /// already packed: `cargo test --release -p w3d-diffusion --lib bf16::tests::block_rate --
    /// --ignored --nocapture`. Measured on the 2-core Zen 5 (load average about 3): 249–260
    /// GMAC/s per core at every shape below, the instruction's peak (2 per cycle, 256 GMAC/s
    /// at 4 GHz; 8.0 G `vdpbf16ps` per second measured in a loop of independent ones).
    #[test]
    #[ignore = "timing: run with --ignored --nocapture"]
    fn block_rate() {
        if !simd_available() {
            return;
        }
        // (activation lines, weight lines, k, activations) of a task at the real-size UNet's shapes.
        for (act_lines, wt_lines, k, activations) in [
            (112usize, 320usize, 320usize, Activations::A),
            (112, 2560, 320, Activations::A),
            (112, 640, 2560, Activations::A),
            (256, 320, 2880, Activations::B),
            (256, 640, 5760, Activations::B),
            (256, 320, 11520, Activations::B),
        ] {
            let (aw, ww) = if activations == Activations::A { (MR, NR) } else { (NR, MR) };
            let passes = Passes::new(k);
            let word = pair(1.0, 1.0);
            let weight = vec![word; wt_lines.div_ceil(ww) * ww * passes.pairs];
            let packed = vec![word; act_lines.div_ceil(aw) * aw * passes.pairs];
            let gather = |_: Range<usize>, _: Range<usize>, dst: &mut [u32], _: &mut Scratch| dst.fill(word);
            let product =
                Product { passes, act_lines, wt_lines, weight: &weight, activations, gather: &gather, simd: true };
            let mut buf = Buffers::default();
            let mut best = f64::MAX;
            for _ in 0..20 {
                let start = std::time::Instant::now();
                product.block(0..act_lines, 0..wt_lines, Some(&packed), &mut buf);
                best = best.min(start.elapsed().as_secs_f64());
            }
            let macs = (act_lines * wt_lines * k) as f64;
            eprintln!("{act_lines} × {wt_lines} × {k} ({activations:?}): {:.0} GMAC/s", macs / best / 1e9);
        }
    }
}
