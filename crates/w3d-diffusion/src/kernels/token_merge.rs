//! Training-free token merging before a multi-view self-attention, and the copy back after it
//! (ToMe for Stable Diffusion, Bolya & Hoffman 2023, reimplemented from the paper's
//! description), on plain `f32` slices `[sequences, views·h·w, channels]`.
//!
//! Why: at the multi-view UNet's highest-resolution level every transformer block's
//! self-attention runs over the tokens of all 6 views of a group (6 × 1024 tokens at real
//! size), the model's most expensive layer, and neighbouring latent tokens are often nearly
//! the same. Merging a fraction `r` of the tokens into their most similar remaining token
//! shrinks the projections by `1 − r` and the attention's score matrix by `(1 − r)²`.
//!
//! The algorithm ([`MergeMap::plan`]), per sequence:
//! - *destinations*: one token per 2×2 patch of each view's `h × w` grid, always the patch's
//!   top-left token (the paper draws the position at random per patch; a fixed one makes the
//!   result a function of the input alone, as the crate's determinism rule asks); every other
//!   token is a *source*;
//! - *similarity*: the cosine of two tokens (the attention's input, i.e. after the block's
//!   `norm1`), computed per view as one GEMM of the unit-length sources by the unit-length
//!   destinations;
//! - *matching*: each source's best destination is its most similar destination **of the same
//!   view** (a cross-view match would average tokens of different views and blur them);
//! - *selection*: the `round(r·N)` sources with the highest best-similarity over the whole
//!   sequence of `N` tokens are merged (at most all sources, i.e. `r ≤ 0.75` takes effect);
//!   ties go to the lower token index;
//! - *merge* ([`MergeMap::merge`]): a destination's reduced token is the mean of itself and
//!   every source merged into it; kept tokens stay in their original order;
//! - *unmerge* ([`MergeMap::unmerge`]): every token takes the attention output of the reduced
//!   token it went into (a merged source gets its destination's output), a gather.
//!
//! The attention runs on the reduced set for queries and keys/values alike, without the
//! paper's optional proportional attention (ToMe for SD found it unnecessary for image
//! quality); the block's residual connection then adds each token's own input back.

use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

use crate::kernels::dispatch::{cpu_inference_f32, cpu_values};
use crate::kernels::gemm::{MatMut, MatRef, gemm_f32};

/// Sources per similarity block: a block's scores are `SOURCE_BLOCK × destinations` values
/// (at the real-size 32×32 level, 256 × 256 floats = 256 KiB, one core's L2), so the memory
/// stays bounded whatever the view's size.
const SOURCE_BLOCK: usize = 256;

/// The layout of sequences of multi-view tokens: `[sequences, views·height·width, channels]`,
/// each view's tokens row-major over its `height × width` latent grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ViewTokens {
    /// Independent sequences (multi-view groups).
    pub sequences: usize,
    /// Views per sequence, each `height · width` consecutive tokens.
    pub views: usize,
    /// Rows of a view's latent grid.
    pub height: usize,
    /// Columns of a view's latent grid.
    pub width: usize,
    /// Channels per token.
    pub channels: usize,
}

impl ViewTokens {
    /// Tokens per view.
    fn per_view(&self) -> usize {
        self.height * self.width
    }

    /// Tokens per sequence, `N`.
    pub(crate) fn tokens(&self) -> usize {
        self.views * self.per_view()
    }

    /// Destinations per view: one per (possibly partial, at odd sizes) 2×2 patch.
    fn destinations_per_view(&self) -> usize {
        self.height.div_ceil(2) * self.width.div_ceil(2)
    }

    /// Sources per sequence: the tokens that may merge.
    fn sources(&self) -> usize {
        self.views * (self.per_view() - self.destinations_per_view())
    }

    /// Whether the token at `(row, col)` of a view is its patch's destination (the top-left).
    fn is_destination(&self, local: usize) -> bool {
        let (row, col) = (local / self.width, local % self.width);
        row % 2 == 0 && col % 2 == 0
    }
}

/// Sources merged out of each sequence of `shape` at ratio `ratio`: `round(ratio · N)`,
/// clamped to `[0, sources]` (only the ¾ of the tokens that are not destinations can merge; a
/// negative or NaN ratio merges none).
pub(crate) fn merged_count(shape: ViewTokens, ratio: f32) -> usize {
    let wanted = (f64::from(ratio) * shape.tokens() as f64).round();
    if wanted.is_nan() || wanted <= 0.0 { 0 } else { (wanted as usize).min(shape.sources()) }
}

/// Where each token of each sequence goes in the reduced sequences: built by
/// [`MergeMap::plan`], applied by [`MergeMap::merge`] and undone by [`MergeMap::unmerge`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct MergeMap {
    /// The layout of the full sequences.
    shape: ViewTokens,
    /// Tokens per reduced sequence (the same for every sequence): `N − merged_count`.
    kept: usize,
    /// `[sequences, N]`: the index in its reduced sequence of each token (a merged source
    /// shares its destination's index).
    target: Vec<u32>,
}

/// A source token's best match in its view: its most similar destination.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// Cosine similarity to the destination.
    similarity: f32,
    /// The source's token index in its sequence.
    source: u32,
    /// The destination's token index in its sequence.
    destination: u32,
}

impl MergeMap {
    /// Plans the merge of `x [sequences, N, channels]` (laid out as `shape` says) at ratio
    /// `ratio`: [`merged_count`] sources per sequence merge into their most similar destination
    /// of the same view (see the module docs). Deterministic: a function of `x` alone.
    ///
    /// # Panics
    /// If `x`'s length does not match `shape` or a sequence has `u32::MAX` tokens or more (a
    /// programming error: the caller builds both from one tensor).
    pub(crate) fn plan(x: &[f32], shape: ViewTokens, ratio: f32) -> Self {
        let (n, c) = (shape.tokens(), shape.channels);
        assert_eq!(x.len(), shape.sequences * n * c, "token_merge: input length");
        assert!(u32::try_from(n).is_ok(), "token_merge: too many tokens for u32 indices");
        let merged = merged_count(shape, ratio);
        let kept = n - merged;
        if merged == 0 {
            let target = (0..shape.sequences).flat_map(|_| 0..n as u32).collect();
            return Self { shape, kept, target };
        }
        // Best destination of every source, one task per (sequence, view).
        let per_view = shape.per_view();
        let matches: Vec<Vec<Candidate>> = (0..shape.sequences * shape.views)
            .into_par_iter()
            .map(|sv| {
                let first = sv * per_view;
                let view_offset = (sv % shape.views) * per_view;
                best_destinations(&x[first * c..(first + per_view) * c], shape, view_offset)
            })
            .collect();
        let mut target = vec![0u32; shape.sequences * n];
        target.par_chunks_mut(n).zip(matches.par_chunks(shape.views)).for_each(|(target, views)| {
            let mut candidates: Vec<Candidate> = views.iter().flatten().copied().collect();
            // Highest similarity first; equal similarities by token index (a total order, so
            // the selection does not depend on the sort's algorithm).
            candidates.sort_unstable_by(|a, b| b.similarity.total_cmp(&a.similarity).then(a.source.cmp(&b.source)));
            let chosen = &candidates[..merged];
            let mut is_merged = vec![false; n];
            for m in chosen {
                is_merged[m.source as usize] = true;
            }
            // Kept tokens in their original order, then each merged source onto its
            // destination's slot (destinations are never merged, so theirs is set).
            let mut next = 0u32;
            for (t, merged) in target.iter_mut().zip(&is_merged) {
                if !merged {
                    *t = next;
                    next += 1;
                }
            }
            for m in chosen {
                target[m.source as usize] = target[m.destination as usize];
            }
        });
        Self { shape, kept, target }
    }

    /// Tokens per reduced sequence.
    pub(crate) fn kept(&self) -> usize {
        self.kept
    }

    /// The reduced sequences `[sequences, kept, channels]` of `x [sequences, N, channels]`:
    /// each kept token is the mean of the tokens that went into it (itself alone, or a
    /// destination and the sources merged into it). The mean is accumulated as a running mean
    /// `m += (x − m)/k` in token order, so tokens that are all equal give exactly their value.
    ///
    /// # Panics
    /// If `x`'s length does not match the planned shape.
    pub(crate) fn merge(&self, x: &[f32]) -> Vec<f32> {
        let (n, c) = (self.shape.tokens(), self.shape.channels);
        assert_eq!(x.len(), self.shape.sequences * n * c, "token_merge: merge input length");
        let mut out = vec![0.0f32; self.shape.sequences * self.kept * c];
        if out.is_empty() {
            return out;
        }
        out.par_chunks_mut(self.kept * c).zip(x.par_chunks(n * c)).zip(self.target.par_chunks(n)).for_each(
            |((out, x), target)| {
                let mut count = vec![0u32; self.kept];
                for (row, &t) in x.chunks_exact(c).zip(target) {
                    let t = t as usize;
                    count[t] += 1;
                    let acc = &mut out[t * c..(t + 1) * c];
                    if count[t] == 1 {
                        acc.copy_from_slice(row);
                    } else {
                        let inv = 1.0 / count[t] as f32;
                        for (a, &v) in acc.iter_mut().zip(row) {
                            *a += (v - *a) * inv;
                        }
                    }
                }
            },
        );
        out
    }

    /// The full sequences `[sequences, N, channels]` from reduced ones `y [sequences, kept,
    /// channels]`: every token takes the row of the reduced token it went into.
    ///
    /// # Panics
    /// If `y`'s length does not match the planned shape.
    pub(crate) fn unmerge(&self, y: &[f32]) -> Vec<f32> {
        let (n, c) = (self.shape.tokens(), self.shape.channels);
        assert_eq!(y.len(), self.shape.sequences * self.kept * c, "token_merge: unmerge input length");
        let mut out = vec![0.0f32; self.shape.sequences * n * c];
        if out.is_empty() {
            return out;
        }
        out.par_chunks_mut(c).zip(self.target.par_iter()).enumerate().for_each(|(token, (row, &t))| {
            let from = (token / n * self.kept + t as usize) * c;
            row.copy_from_slice(&y[from..from + c]);
        });
        out
    }
}

/// The best destination of every source of one view `x [h·w, channels]` whose first token
/// has index `view_offset` in its sequence: the GEMM of the unit-length sources by the
/// unit-length destinations in blocks of [`SOURCE_BLOCK`] sources, then each row's first
/// maximum.
fn best_destinations(x: &[f32], shape: ViewTokens, view_offset: usize) -> Vec<Candidate> {
    let c = shape.channels;
    let (destinations, sources): (Vec<usize>, Vec<usize>) =
        (0..shape.per_view()).partition(|&local| shape.is_destination(local));
    let dst = unit_rows(x, &destinations, c);
    let src = unit_rows(x, &sources, c);
    let nd = destinations.len();
    let mut scores = vec![0.0f32; SOURCE_BLOCK.min(sources.len()) * nd];
    let mut out = Vec::with_capacity(sources.len());
    for s0 in (0..sources.len()).step_by(SOURCE_BLOCK) {
        let rows = SOURCE_BLOCK.min(sources.len() - s0);
        let scores = &mut scores[..rows * nd];
        // scores[rows × nd] = src_block · dstᵀ (dst rows read with swapped strides).
        gemm_f32(
            MatMut { data: scores, rows, cols: nd, row_stride: nd, col_stride: 1 },
            MatRef { data: &src[s0 * c..], rows, cols: c, row_stride: c, col_stride: 1 },
            MatRef { data: &dst, rows: c, cols: nd, row_stride: 1, col_stride: c },
            false,
            1.0,
        );
        for (i, row) in scores.chunks_exact(nd).enumerate() {
            let (mut best, mut similarity) = (0, row[0]);
            for (j, &s) in row.iter().enumerate().skip(1) {
                if s > similarity {
                    (best, similarity) = (j, s);
                }
            }
            out.push(Candidate {
                similarity,
                source: (view_offset + sources[s0 + i]) as u32,
                destination: (view_offset + destinations[best]) as u32,
            });
        }
    }
    out
}

/// Rows `rows` of `x` (`channels` wide) scaled to unit length, `[rows.len(), channels]`; a
/// zero row stays zero (similarity 0 to everything).
fn unit_rows(x: &[f32], rows: &[usize], channels: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(rows.len() * channels);
    for &r in rows {
        let row = &x[r * channels..(r + 1) * channels];
        let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt();
        let inv = if norm > 0.0 { 1.0 / norm } else { 0.0 };
        out.extend(row.iter().map(|v| v * inv));
    }
    out
}

/// `attend` (a token-sequence map that treats its tokens as a set, such as a self-attention)
/// applied to the tokens of `x [sequences, views·height·width, channels]` merged at ratio
/// `ratio`, its output copied back to every merged token ([`MergeMap`]): `attend` sees
/// `[sequences, N − round(ratio·N), channels]` and returns the same shape.
///
/// Only on tensors the crate's CPU inference kernels take ([`cpu_inference_f32`]: f32 on a
/// CPU backend, no autodiff graph) and when at least one token merges; otherwise exactly
/// `attend(x)`.
pub(crate) fn with_merged_tokens(
    x: Tensor<3>,
    views: usize,
    (height, width): (usize, usize),
    ratio: f32,
    attend: impl FnOnce(Tensor<3>) -> Tensor<3>,
) -> Tensor<3> {
    let [sequences, tokens, channels] = x.dims();
    let shape = ViewTokens { sequences, views, height, width, channels };
    if tokens != shape.tokens() || merged_count(shape, ratio) == 0 || !cpu_inference_f32(&x) {
        return attend(x);
    }
    let device = x.device();
    let values = cpu_values(x);
    let map = MergeMap::plan(&values, shape, ratio);
    let reduced = Tensor::from_data(TensorData::new(map.merge(&values), [sequences, map.kept(), channels]), &device);
    let out = attend(reduced);
    let out_channels = out.dims()[2];
    let full = MergeMap { shape: ViewTokens { channels: out_channels, ..shape }, ..map }.unmerge(&cpu_values(out));
    Tensor::from_data(TensorData::new(full, [sequences, tokens, out_channels]), &device)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random values in `[-1, 1)` (a 64-bit LCG; the tests need no
    /// distribution, only distinct directions).
    fn noise(len: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1);
        (0..len)
            .map(|_| {
                s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// Token `t` of sequence `s` (a row of `channels` values).
    fn token(x: &[f32], shape: ViewTokens, s: usize, t: usize) -> &[f32] {
        let c = shape.channels;
        let at = (s * shape.tokens() + t) * c;
        &x[at..at + c]
    }

    /// Copies token `from` of sequence `s` onto token `to`, scaled by `scale`.
    fn copy_token(x: &mut [f32], shape: ViewTokens, s: usize, from: usize, to: usize, scale: f32) {
        let row: Vec<f32> = token(x, shape, s, from).iter().map(|v| v * scale).collect();
        let c = shape.channels;
        let at = (s * shape.tokens() + to) * c;
        x[at..at + c].copy_from_slice(&row);
    }

    const SHAPE: ViewTokens = ViewTokens { sequences: 2, views: 3, height: 4, width: 6, channels: 8 };

    /// Index in its sequence of token `(row, col)` of view `v`.
    fn at(shape: ViewTokens, v: usize, row: usize, col: usize) -> usize {
        v * shape.per_view() + row * shape.width + col
    }

    #[test]
    fn identical_tokens_in_a_patch_merge_first() {
        let mut x = noise(SHAPE.sequences * SHAPE.tokens() * SHAPE.channels, 1);
        // In sequence 1: a source that equals its patch's destination, another that is a
        // multiple of it (cosine 1 as well), in two views.
        copy_token(&mut x, SHAPE, 1, at(SHAPE, 1, 2, 2), at(SHAPE, 1, 3, 3), 1.0);
        copy_token(&mut x, SHAPE, 1, at(SHAPE, 2, 0, 4), at(SHAPE, 2, 0, 5), 3.0);
        let ratio = 2.0 / SHAPE.tokens() as f32;
        let map = MergeMap::plan(&x, SHAPE, ratio);
        assert_eq!(map.kept(), SHAPE.tokens() - 2);
        let n = SHAPE.tokens();
        let seq1 = &map.target[n..];
        assert_eq!(seq1[at(SHAPE, 1, 3, 3)], seq1[at(SHAPE, 1, 2, 2)]);
        assert_eq!(seq1[at(SHAPE, 2, 0, 5)], seq1[at(SHAPE, 2, 0, 4)]);
        // Nothing else merged there: the other targets are distinct.
        let mut distinct: Vec<u32> = seq1.to_vec();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), n - 2);
        // The merged token is the mean of the destination and its source(s): here 2u from
        // u and 3u.
        let reduced = map.merge(&x);
        let c = SHAPE.channels;
        let t = seq1[at(SHAPE, 2, 0, 4)] as usize;
        let got = &reduced[(map.kept() + t) * c..(map.kept() + t + 1) * c];
        for (g, u) in got.iter().zip(token(&x, SHAPE, 1, at(SHAPE, 2, 0, 4))) {
            assert!((g - 2.0 * u).abs() <= 1e-6, "{g} vs {}", 2.0 * u);
        }
    }

    #[test]
    fn matching_stays_within_a_view() {
        let mut x = noise(SHAPE.sequences * SHAPE.tokens() * SHAPE.channels, 2);
        // A source of view 2 equal to a destination of view 0: it must not merge into it.
        copy_token(&mut x, SHAPE, 0, at(SHAPE, 0, 2, 2), at(SHAPE, 2, 1, 1), 1.0);
        let map = MergeMap::plan(&x, SHAPE, 0.75);
        let n = SHAPE.tokens();
        let (pv, c) = (SHAPE.per_view(), SHAPE.channels);
        for s in 0..SHAPE.sequences {
            let target = &map.target[s * n..(s + 1) * n];
            for t in 0..n {
                let view = t / pv;
                let same_view =
                    (view * pv..(view + 1) * pv).any(|d| SHAPE.is_destination(d % pv) && target[d] == target[t]);
                assert!(same_view, "token {t} of sequence {s} left its view");
            }
        }
        assert_ne!(map.target[at(SHAPE, 2, 1, 1)], map.target[at(SHAPE, 0, 2, 2)]);
        assert_eq!(map.merge(&x).len(), SHAPE.sequences * map.kept() * c);
    }

    #[test]
    fn the_reduced_count_is_n_minus_the_rounded_ratio_clamped_to_the_sources() {
        for shape in [SHAPE, ViewTokens { sequences: 1, views: 2, height: 3, width: 5, channels: 4 }] {
            let n = shape.tokens();
            let sources = shape.views * (shape.per_view() - shape.destinations_per_view());
            let x = noise(shape.sequences * n * shape.channels, 3);
            for ratio in [0.0f32, 0.1, 0.25, 0.5, 0.6, 0.75, 0.9] {
                let expected = n - ((ratio * n as f32).round() as usize).min(sources);
                let map = MergeMap::plan(&x, shape, ratio);
                assert_eq!(map.kept(), expected, "ratio {ratio}, shape {shape:?}");
                let reduced = map.merge(&x);
                assert_eq!(reduced.len(), shape.sequences * expected * shape.channels);
                assert_eq!(map.unmerge(&reduced).len(), x.len());
            }
        }
        // 3×5 view: destinations at even rows and columns, 2 × 3 = 6 of 15.
        let odd = ViewTokens { sequences: 1, views: 2, height: 3, width: 5, channels: 4 };
        assert_eq!(odd.sources(), 2 * 9);
        assert_eq!(merged_count(odd, 0.9), 18);
        assert_eq!(merged_count(odd, -0.5), 0);
        assert_eq!(merged_count(odd, f32::NAN), 0);
    }

    #[test]
    fn unmerge_of_merge_restores_tokens_whose_sources_equal_their_destinations() {
        // Every source is a copy of its 2×2 patch's top-left token: whatever merges, the
        // means are exact and the copy back restores every token bit for bit.
        let mut x = noise(SHAPE.sequences * SHAPE.tokens() * SHAPE.channels, 4);
        for s in 0..SHAPE.sequences {
            for v in 0..SHAPE.views {
                for row in 0..SHAPE.height {
                    for col in 0..SHAPE.width {
                        let top_left = at(SHAPE, v, row & !1, col & !1);
                        copy_token(&mut x, SHAPE, s, top_left, at(SHAPE, v, row, col), 1.0);
                    }
                }
            }
        }
        for ratio in [0.25f32, 0.5, 0.75] {
            let map = MergeMap::plan(&x, SHAPE, ratio);
            assert!(map.kept() < SHAPE.tokens());
            let back = map.unmerge(&map.merge(&x));
            assert!(back.iter().zip(&x).all(|(a, b)| a.to_bits() == b.to_bits()), "ratio {ratio}");
        }
        // With ordinary tokens the copy back is not the identity (control).
        let y = noise(x.len(), 5);
        let map = MergeMap::plan(&y, SHAPE, 0.5);
        assert_ne!(map.unmerge(&map.merge(&y)), y);
    }

    #[test]
    fn planning_and_merging_are_deterministic() {
        let x = noise(SHAPE.sequences * SHAPE.tokens() * SHAPE.channels, 6);
        let a = MergeMap::plan(&x, SHAPE, 0.5);
        let b = MergeMap::plan(&x, SHAPE, 0.5);
        assert_eq!(a, b);
        let (ma, mb) = (a.merge(&x), b.merge(&x));
        assert!(ma.iter().zip(&mb).all(|(p, q)| p.to_bits() == q.to_bits()));
        // The same on a single thread as on the pool.
        let single = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let c = single.install(|| MergeMap::plan(&x, SHAPE, 0.5));
        assert_eq!(a, c);
    }

    #[test]
    fn ratio_zero_keeps_every_token_in_order() {
        let x = noise(SHAPE.sequences * SHAPE.tokens() * SHAPE.channels, 7);
        let map = MergeMap::plan(&x, SHAPE, 0.0);
        assert_eq!(map.kept(), SHAPE.tokens());
        assert_eq!(map.merge(&x), x);
        assert_eq!(map.unmerge(&x), x);
    }

    /// Seconds of the fastest of `runs` calls of `f`.
    fn best_of(runs: usize, mut f: impl FnMut()) -> f64 {
        (0..runs)
            .map(|_| {
                let start = std::time::Instant::now();
                f();
                start.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Real-size timing (`cargo test --release -p w3d-diffusion --lib token_merge -- --ignored
    /// --nocapture`): one UNet pass's level-0 multi-view self-attention, 2 sequences of
    /// 6 views × 32 × 32 tokens × 320 channels, 8 heads; merge + attention + unmerge at
    /// r = 0.25, 0.5, 0.75 against the plain attention, and the q/k/v/out projections.
    #[test]
    #[ignore = "timing at real size (seconds); run with --ignored --nocapture"]
    fn real_size_merged_attention_timing() {
        use crate::kernels::attention::{AttentionShape, attention};
        use crate::kernels::dispatch::cpu_values;

        let device = crate::device::default_device();
        let shape = ViewTokens { sequences: 2, views: 6, height: 32, width: 32, channels: 320 };
        let (n, c, heads) = (shape.tokens(), shape.channels, 8);
        // Smooth-ish tokens: a per-view random field plus a slow ramp over the grid, so the
        // similarities are not all alike (timing does not depend on them).
        let mut x = noise(shape.sequences * n * c, 11);
        for (i, v) in x.iter_mut().enumerate() {
            let t = (i / c) % shape.per_view();
            *v = 0.3 * *v + ((t / shape.width) as f32 / 8.0).sin() + ((t % shape.width) as f32 / 8.0).cos();
        }
        let tensor = |values: Vec<f32>, tokens: usize| {
            Tensor::<3>::from_data(TensorData::new(values, [shape.sequences, tokens, c]), &device)
        };
        // The layer's pieces as the kernels and Burn's products compute them at inference.
        let weight = |seed| {
            Tensor::<2>::from_data(
                TensorData::new(noise(c * c, seed).iter().map(|v| v * 0.05).collect(), [c, c]),
                &device,
            )
        };
        let (wq, wk, wv, wo) = (weight(21), weight(22), weight(23), weight(24));
        let project = |t: Tensor<3>, w: &Tensor<2>| {
            let [b, tokens, width] = t.dims();
            t.reshape([b * tokens, width]).matmul(w.clone()).reshape([b, tokens, width])
        };
        let multi_head_attention = |q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize| {
            let [batch, queries, width] = q.dims();
            let shape = AttentionShape { batch, queries, keys: k.dims()[1], heads, head_dim: width / heads };
            let out = attention(&cpu_values(q), &cpu_values(k), &cpu_values(v), shape);
            Tensor::<3>::from_data(TensorData::new(out, [batch, queries, width]), &device)
        };
        let layer = |t: Tensor<3>| {
            let (q, k, v) = (project(t.clone(), &wq), project(t.clone(), &wk), project(t, &wv));
            project(multi_head_attention(q, k, v, heads), &wo)
        };
        let sync = |t: Tensor<3>| std::hint::black_box(t.into_data());
        let runs = 3;
        let full = tensor(x.clone(), n);
        let attention_only = best_of(runs, || {
            sync(multi_head_attention(full.clone(), full.clone(), full.clone(), heads));
        });
        let projections = best_of(runs, || {
            for w in [&wq, &wk, &wv, &wo] {
                sync(project(full.clone(), w));
            }
        });
        let plain = best_of(runs, || {
            sync(layer(full.clone()));
        });
        let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
        println!("loadavg before: {}", load.trim());
        println!(
            "plain: attention {:.1} ms, q/k/v/out projections {:.1} ms, layer {:.1} ms ({n} tokens)",
            attention_only * 1e3,
            projections * 1e3,
            plain * 1e3
        );
        for ratio in [0.25f32, 0.5, 0.75] {
            let map = MergeMap::plan(&x, shape, ratio);
            let kept = map.kept();
            let plan = best_of(runs, || {
                std::hint::black_box(MergeMap::plan(&x, shape, ratio));
            });
            let merge = best_of(runs, || {
                std::hint::black_box(map.merge(&x));
            });
            let reduced = tensor(map.merge(&x), kept);
            let attention = best_of(runs, || {
                sync(multi_head_attention(reduced.clone(), reduced.clone(), reduced.clone(), heads));
            });
            let projections = best_of(runs, || {
                for w in [&wq, &wk, &wv, &wo] {
                    sync(project(reduced.clone(), w));
                }
            });
            let out = map.merge(&x);
            let unmerge = best_of(runs, || {
                std::hint::black_box(map.unmerge(&out));
            });
            let whole = best_of(runs, || {
                let values = x.clone();
                sync(with_merged_tokens(tensor(values, n), shape.views, (shape.height, shape.width), ratio, layer));
            });
            println!(
                "r = {ratio}: {kept} tokens kept; plan {:.1} ms, merge {:.1} ms, attention {:.1} ms, \
                 projections {:.1} ms, unmerge {:.1} ms; whole layer merged {:.1} ms vs plain {:.1} ms ({:.2}×)",
                plan * 1e3,
                merge * 1e3,
                attention * 1e3,
                projections * 1e3,
                unmerge * 1e3,
                whole * 1e3,
                plain * 1e3,
                plain / whole
            );
        }
        let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
        println!("loadavg after: {}", load.trim());
    }
}
