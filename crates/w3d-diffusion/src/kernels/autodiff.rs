//! The crate's CPU kernels as differentiable operations on Burn's flex backend: multi-head
//! attention ([`crate::kernels::attention`]), 2-D convolution ([`crate::kernels::conv`]), group
//! normalisation with its SiLU ([`crate::kernels::group_norm`]), the feed-forward's GEGLU gate
//! ([`crate::kernels::geglu`]) and the fully connected layer ([`crate::kernels::linear`]), each one node
//! of Burn's autodiff graph with a hand-written backward, so that training on the CPU neither differentiates
//! through the dozen tensor operations of Burn's attention or group norm nor computes a
//! convolution's input gradient with flex's transposed convolution (`docs/benchmarks.md`,
//! "Training step").
//!
//! Burn's autodiff attention is its generic composition (a matmul, the scale, the maximum,
//! the exponential, the sum, the division and a second matmul), each op tracked: the backward
//! walks every one of them over the whole score matrix, several passes of memory traffic per
//! attention. Here the forward keeps only the inputs, the output and one normaliser per query
//! and head; the backward recomputes the weights block by block and runs five GEMMs per block
//! ([`crate::kernels::attention::attention_backward`]). The convolution keeps its input and weight
//! and runs one GEMM per image for each gradient ([`crate::kernels::conv::conv2d_backward`]).
//!
//! All four agree with Burn's own operations, values and gradients, to f32 rounding (the
//! GEGLU gate bit for bit; `tests/parity_cases/attention.rs`, `tests/parity_cases/conv.rs`,
//! `tests/parity_cases/group_norm.rs`, `tests/parity_cases/geglu.rs`).

use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::{BalancedCheckpointing, CheckpointStrategy, NoCheckpointing};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, NodeGuard, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use std::sync::Arc;

use burn::tensor::{DType, GradientCheckpointingStrategy, Shape, Tensor, TensorData};

use crate::kernels::attention::{AttentionShape, attention_backward, attention_with_lse};
use crate::kernels::conv::{conv2d, conv2d_backward};
use crate::kernels::conv_shape::ConvShape;
use crate::kernels::geglu::{geglu, geglu_backward};
use crate::kernels::group_norm::{GroupNormShape, GroupStats, group_norm, group_norm_backward};
use crate::kernels::linear::{LinearShape, linear, linear_backward};

/// Where the fused attention applies: `q`, `k` and `v` are f32 flex tensors under autodiff with
/// one checkpointing strategy (returned) and at least one query and one key.
pub(crate) fn attention_applies(q: &Tensor<3>, k: &Tensor<3>, v: &Tensor<3>) -> Option<GradientCheckpointingStrategy> {
    let strategy = shared_strategy(&[autodiff_on_flex(q), autodiff_on_flex(k), autodiff_on_flex(v)])?;
    (q.dims()[1] > 0 && k.dims()[1] > 0).then_some(strategy)
}

/// `softmax(q·kᵀ/√d)·v` over `[b, t, h·d]` sequences split into `heads` heads, as a single
/// autodiff operation; `strategy` from [`attention_applies`].
pub(crate) fn attention(
    q: Tensor<3>,
    k: Tensor<3>,
    v: Tensor<3>,
    heads: usize,
    strategy: GradientCheckpointingStrategy,
) -> Tensor<3> {
    match strategy {
        GradientCheckpointingStrategy::Balanced => fused_attention::<BalancedCheckpointing>(q, k, v, heads),
        GradientCheckpointingStrategy::Disabled => fused_attention::<NoCheckpointing>(q, k, v, heads),
    }
}

/// Where the fused convolution applies: every tensor an f32 flex tensor under autodiff with one
/// checkpointing strategy (returned), matching channel counts, a square kernel that fits the
/// padded input and a `[o]` bias.
pub(crate) fn conv2d_applies(
    x: &Tensor<4>,
    weight: &Tensor<4>,
    bias: Option<&Tensor<1>>,
    stride: usize,
    padding: usize,
) -> Option<GradientCheckpointingStrategy> {
    let mut tensors = vec![autodiff_on_flex(x), autodiff_on_flex(weight)];
    tensors.extend(bias.map(autodiff_on_flex));
    let strategy = shared_strategy(&tensors)?;
    let shape = conv_shape(x, weight, stride, padding);
    let [_, c_w, _, kernel_w] = weight.dims();
    let fits = c_w == shape.c_in && kernel_w == shape.kernel && shape.output().is_some();
    (fits && bias.is_none_or(|b| b.dims() == [shape.c_out])).then_some(strategy)
}

/// `x` convolved with `weight` (`[o, c, k, k]`) plus `bias`, stride and zero padding as given,
/// as a single autodiff operation; `strategy` from [`conv2d_applies`].
pub(crate) fn conv2d_op(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    stride: usize,
    padding: usize,
    strategy: GradientCheckpointingStrategy,
) -> Tensor<4> {
    let shape = conv_shape(&x, &weight, stride, padding);
    match strategy {
        GradientCheckpointingStrategy::Balanced => fused_conv2d::<BalancedCheckpointing>(x, weight, bias, shape),
        GradientCheckpointingStrategy::Disabled => fused_conv2d::<NoCheckpointing>(x, weight, bias, shape),
    }
}

fn conv_shape(x: &Tensor<4>, weight: &Tensor<4>, stride: usize, padding: usize) -> ConvShape {
    let [batch, c_in, height, width] = x.dims();
    let [c_out, _, kernel, _] = weight.dims();
    ConvShape { batch, c_in, height, width, c_out, kernel, stride, padding }
}

/// Where the fused group normalisation applies: every tensor an f32 flex tensor under autodiff
/// with one checkpointing strategy (returned), `c` a multiple of `groups`, `[c]` weight and
/// bias.
pub(crate) fn group_norm_applies(
    x: &Tensor<4>,
    weight: &Tensor<1>,
    bias: &Tensor<1>,
    groups: usize,
) -> Option<GradientCheckpointingStrategy> {
    let strategy = shared_strategy(&[autodiff_on_flex(x), autodiff_on_flex(weight), autodiff_on_flex(bias)])?;
    let c = x.dims()[1];
    let fits = groups > 0 && c.is_multiple_of(groups) && weight.dims() == [c] && bias.dims() == [c];
    fits.then_some(strategy)
}

/// Group normalisation of `x` (`[n, c, h, w]`, `groups` groups of channels, per-channel
/// `weight` and `bias`), followed by SiLU when `silu`, as a single autodiff operation;
/// `strategy` from [`group_norm_applies`].
pub(crate) fn group_norm_op(
    x: Tensor<4>,
    weight: Tensor<1>,
    bias: Tensor<1>,
    groups: usize,
    eps: f64,
    silu: bool,
    strategy: GradientCheckpointingStrategy,
) -> Tensor<4> {
    let [batch, channels, h, w] = x.dims();
    let shape = GroupNormShape { batch, channels, pixels: h * w, groups };
    match strategy {
        GradientCheckpointingStrategy::Balanced => {
            fused_group_norm::<BalancedCheckpointing>(x, weight, bias, shape, eps, silu)
        }
        GradientCheckpointingStrategy::Disabled => {
            fused_group_norm::<NoCheckpointing>(x, weight, bias, shape, eps, silu)
        }
    }
}

/// Where the fused GEGLU gate applies: `projection` is an f32 flex tensor under autodiff (its
/// checkpointing strategy is returned) whose last dimension is even and non-zero.
pub(crate) fn geglu_applies(projection: &Tensor<3>) -> Option<GradientCheckpointingStrategy> {
    let two_inner = projection.dims()[2];
    autodiff_on_flex(projection).filter(|_| two_inner > 0 && two_inner.is_multiple_of(2))
}

/// `hidden · gelu(gate)` of the halves `[hidden, gate]` of the last dimension of `projection`
/// (`[n, t, 2·inner]` → `[n, t, inner]`) as a single autodiff operation; `strategy` from
/// [`geglu_applies`].
pub(crate) fn geglu_op(projection: Tensor<3>, strategy: GradientCheckpointingStrategy) -> Tensor<3> {
    match strategy {
        GradientCheckpointingStrategy::Balanced => fused_geglu::<BalancedCheckpointing>(projection),
        GradientCheckpointingStrategy::Disabled => fused_geglu::<NoCheckpointing>(projection),
    }
}

/// Where the fused fully connected layer applies: every tensor an f32 flex tensor under
/// autodiff with one checkpointing strategy (returned), `x` `[rows, in]`, the weight `[in,
/// out]` and the bias `[out]`.
pub(crate) fn linear_applies(
    x: &Tensor<2>,
    weight: &Tensor<2>,
    bias: Option<&Tensor<1>>,
) -> Option<GradientCheckpointingStrategy> {
    let mut tensors = vec![autodiff_on_flex(x), autodiff_on_flex(weight)];
    tensors.extend(bias.map(autodiff_on_flex));
    let strategy = shared_strategy(&tensors)?;
    let ([_, d_in], [w_in, d_out]) = (x.dims(), weight.dims());
    (d_in == w_in && bias.is_none_or(|b| b.dims() == [d_out])).then_some(strategy)
}

/// `x·W + b` (`[rows, in]` → `[rows, out]`, the weight `[in, out]`) as a single autodiff
/// operation; `strategy` from [`linear_applies`].
pub(crate) fn linear_op(
    x: Tensor<2>,
    weight: Tensor<2>,
    bias: Option<Tensor<1>>,
    strategy: GradientCheckpointingStrategy,
) -> Tensor<2> {
    let ([rows, d_in], [_, d_out]) = (x.dims(), weight.dims());
    let shape = LinearShape { rows, d_in, d_out };
    match strategy {
        GradientCheckpointingStrategy::Balanced => fused_linear::<BalancedCheckpointing>(x, weight, bias, shape),
        GradientCheckpointingStrategy::Disabled => fused_linear::<NoCheckpointing>(x, weight, bias, shape),
    }
}

/// A tensor's checkpointing strategy when it is an f32 flex tensor under autodiff.
fn autodiff_on_flex<const D: usize>(t: &Tensor<D>) -> Option<GradientCheckpointingStrategy> {
    let eligible = t.dtype() == DType::F32 && t.is_autodiff() && crate::kernels::dispatch::on_flex(&t.device());
    eligible.then(|| t.gradient_checkpointing_strategy()).flatten()
}

/// The one strategy all operands share, `None` if one is not eligible or they differ.
fn shared_strategy(strategies: &[Option<GradientCheckpointingStrategy>]) -> Option<GradientCheckpointingStrategy> {
    let first = strategies.first().copied().flatten()?;
    strategies.iter().all(|s| *s == Some(first)).then_some(first)
}

/// The autodiff primitive of an f32 flex tensor (the same type for every checkpointing strategy).
type FlexAutodiffTensor = <Autodiff<Flex> as burn::backend::BackendTypes>::FloatTensorPrimitive;

/// Converts to and from the autodiff primitive for one checkpointing strategy; the bound Burn
/// places on that conversion is private, so the two strategies are spelled out.
trait FlexAutodiff: CheckpointStrategy {
    fn into_primitive<const D: usize>(t: Tensor<D>) -> FlexAutodiffTensor;
    fn from_primitive<const D: usize>(t: FlexAutodiffTensor) -> Tensor<D>;
}

macro_rules! flex_autodiff {
    ($strategy:ty) => {
        impl FlexAutodiff for $strategy {
            fn into_primitive<const D: usize>(t: Tensor<D>) -> FlexAutodiffTensor {
                t.try_into_primitive::<Autodiff<Flex, $strategy>>()
                    .expect("an autodiff flex tensor with this strategy (checked by the caller)")
            }
            fn from_primitive<const D: usize>(t: FlexAutodiffTensor) -> Tensor<D> {
                Tensor::from_primitive::<Autodiff<Flex, $strategy>>(t)
            }
        }
    };
}
flex_autodiff!(NoCheckpointing);
flex_autodiff!(BalancedCheckpointing);

/// The attention's backward record: the inputs and output (shared, not copied), the
/// normalisers and the shape.
#[derive(Clone, Debug)]
struct AttentionState {
    q: FlexTensor,
    k: FlexTensor,
    v: FlexTensor,
    out: FlexTensor,
    lse: Arc<Vec<f32>>,
    shape: AttentionShape,
}

#[derive(Debug)]
struct FusedAttention;

impl Backward<Flex, 3> for FusedAttention {
    type State = AttentionState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let grad = contiguous(grads.consume::<Flex>(&ops.node));
        let s = &ops.state;
        let (dq, dk, dv) =
            attention_backward(f32s(&s.q), f32s(&s.k), f32s(&s.v), f32s(&s.out), &s.lse, f32s(&grad), s.shape);
        let parents = ops.parents.iter().map(|p| p.as_ref().map(|node| node.id));
        register_grads(
            grads,
            parents,
            [(Some(dq), shape_of(&s.q)), (Some(dk), shape_of(&s.k)), (Some(dv), shape_of(&s.v))],
        );
    }
}

fn fused_attention<C: FlexAutodiff>(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize) -> Tensor<3> {
    let [batch, queries, width] = q.dims();
    let keys = k.dims()[1];
    let shape = AttentionShape { batch, queries, keys, heads, head_dim: width / heads };
    let (q, k, v) = (C::into_primitive(q), C::into_primitive(k), C::into_primitive(v));
    let [qp, kp, vp] = [q.primitive(), k.primitive(), v.primitive()].map(|t| contiguous(t.clone()));
    let (out, lse) = attention_with_lse(f32s(&qp), f32s(&kp), f32s(&vp), shape);
    let out = FlexTensor::from_data(TensorData::new(out, [batch, queries, width]));
    let kept = out.clone();
    let state = move || AttentionState { q: qp, k: kp, v: vp, out: kept, lse: Arc::new(lse), shape };
    C::from_primitive(record::<C, _, 3>(FusedAttention, [q.node(), k.node(), v.node()], state, out))
}

/// The convolution's backward record: the input and weight (shared, not copied) and the shape.
#[derive(Clone, Debug)]
struct ConvState {
    x: FlexTensor,
    weight: FlexTensor,
    shape: ConvShape,
}

/// The convolution node; `N` is 3 with a bias, 2 without (parents: input, weight, bias).
#[derive(Debug)]
struct FusedConv2d<const N: usize>;

impl<const N: usize> Backward<Flex, N> for FusedConv2d<N> {
    type State = ConvState;

    fn backward(self, ops: Ops<Self::State, N>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let grad = contiguous(grads.consume::<Flex>(&ops.node));
        let s = &ops.state;
        let want = [0, 1, 2].map(|i| ops.parents.get(i).is_some_and(Option::is_some));
        let [dx, dw, db] = conv2d_backward(f32s(&s.x), f32s(&s.weight), f32s(&grad), s.shape, want);
        let parents = ops.parents.iter().map(|p| p.as_ref().map(|node| node.id));
        register_grads(grads, parents, [(dx, shape_of(&s.x)), (dw, shape_of(&s.weight)), (db, [s.shape.c_out].into())]);
    }
}

fn fused_conv2d<C: FlexAutodiff>(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    shape: ConvShape,
) -> Tensor<4> {
    let (x, weight) = (C::into_primitive(x), C::into_primitive(weight));
    let bias = bias.map(C::into_primitive);
    let (xp, wp) = (contiguous(x.primitive().clone()), contiguous(weight.primitive().clone()));
    let bp = bias.as_ref().map(|b| contiguous(b.primitive().clone()));
    let out = conv2d(f32s(&xp), f32s(&wp), bp.as_ref().map(f32s), shape);
    let (ho, wo) = shape.output().expect("checked by conv2d_applies");
    let out = FlexTensor::from_data(TensorData::new(out, [shape.batch, shape.c_out, ho, wo]));
    let state = || ConvState { x: xp.clone(), weight: wp.clone(), shape };
    let result = match bias {
        Some(b) => record::<C, _, 3>(FusedConv2d::<3>, [x.node(), weight.node(), b.node()], state, out),
        None => record::<C, _, 2>(FusedConv2d::<2>, [x.node(), weight.node()], state, out),
    };
    C::from_primitive(result)
}

/// The fully connected layer's backward record: the input and weight (shared, not copied) and
/// the shape.
#[derive(Clone, Debug)]
struct LinearState {
    x: FlexTensor,
    weight: FlexTensor,
    shape: LinearShape,
}

/// The fully connected layer's node; `N` is 3 with a bias, 2 without (parents: input, weight,
/// bias).
#[derive(Debug)]
struct FusedLinear<const N: usize>;

impl<const N: usize> Backward<Flex, N> for FusedLinear<N> {
    type State = LinearState;

    fn backward(self, ops: Ops<Self::State, N>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let grad = contiguous(grads.consume::<Flex>(&ops.node));
        let s = &ops.state;
        let want = [0, 1, 2].map(|i| ops.parents.get(i).is_some_and(Option::is_some));
        let [dx, dw, db] = linear_backward(f32s(&s.x), f32s(&s.weight), f32s(&grad), s.shape, want);
        let parents = ops.parents.iter().map(|p| p.as_ref().map(|node| node.id));
        register_grads(grads, parents, [(dx, shape_of(&s.x)), (dw, shape_of(&s.weight)), (db, [s.shape.d_out].into())]);
    }
}

fn fused_linear<C: FlexAutodiff>(
    x: Tensor<2>,
    weight: Tensor<2>,
    bias: Option<Tensor<1>>,
    shape: LinearShape,
) -> Tensor<2> {
    let (x, weight) = (C::into_primitive(x), C::into_primitive(weight));
    let bias = bias.map(C::into_primitive);
    let (xp, wp) = (contiguous(x.primitive().clone()), contiguous(weight.primitive().clone()));
    let bp = bias.as_ref().map(|b| contiguous(b.primitive().clone()));
    let out = linear(f32s(&xp), f32s(&wp), bp.as_ref().map(f32s), shape);
    let out = FlexTensor::from_data(TensorData::new(out, [shape.rows, shape.d_out]));
    let state = || LinearState { x: xp.clone(), weight: wp.clone(), shape };
    let result = match bias {
        Some(b) => record::<C, _, 3>(FusedLinear::<3>, [x.node(), weight.node(), b.node()], state, out),
        None => record::<C, _, 2>(FusedLinear::<2>, [x.node(), weight.node()], state, out),
    };
    C::from_primitive(result)
}

/// The group normalisation's backward record: input, weight and bias (shared, not copied), the
/// per-group statistics, the shape and whether SiLU follows.
#[derive(Clone, Debug)]
struct GroupNormState {
    x: FlexTensor,
    weight: FlexTensor,
    bias: FlexTensor,
    stats: Arc<GroupStats>,
    shape: GroupNormShape,
    silu: bool,
}

#[derive(Debug)]
struct FusedGroupNorm;

impl Backward<Flex, 3> for FusedGroupNorm {
    type State = GroupNormState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let grad = contiguous(grads.consume::<Flex>(&ops.node));
        let s = &ops.state;
        let (dx, dw, db) =
            group_norm_backward(f32s(&s.x), f32s(&s.weight), f32s(&s.bias), &s.stats, f32s(&grad), s.shape, s.silu);
        let parents = ops.parents.iter().map(|p| p.as_ref().map(|node| node.id));
        register_grads(
            grads,
            parents,
            [(Some(dx), shape_of(&s.x)), (Some(dw), shape_of(&s.weight)), (Some(db), shape_of(&s.bias))],
        );
    }
}

fn fused_group_norm<C: FlexAutodiff>(
    x: Tensor<4>,
    weight: Tensor<1>,
    bias: Tensor<1>,
    shape: GroupNormShape,
    eps: f64,
    silu: bool,
) -> Tensor<4> {
    let dims = x.dims();
    let (x, weight, bias) = (C::into_primitive(x), C::into_primitive(weight), C::into_primitive(bias));
    let [xp, wp, bp] = [x.primitive(), weight.primitive(), bias.primitive()].map(|t| contiguous(t.clone()));
    let (out, stats) = group_norm(f32s(&xp), f32s(&wp), f32s(&bp), shape, eps, silu);
    let out = FlexTensor::from_data(TensorData::new(out, dims));
    let state = || GroupNormState { x: xp, weight: wp, bias: bp, stats: Arc::new(stats), shape, silu };
    C::from_primitive(record::<C, _, 3>(FusedGroupNorm, [x.node(), weight.node(), bias.node()], state, out))
}

/// The GEGLU gate's backward record: the projection (shared, not copied).
#[derive(Clone, Debug)]
struct GegluState {
    projection: FlexTensor,
}

#[derive(Debug)]
struct FusedGeglu;

impl Backward<Flex, 1> for FusedGeglu {
    type State = GegluState;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let grad = contiguous(grads.consume::<Flex>(&ops.node));
        let projection = &ops.state.projection;
        let inner = shape_of(projection).dims::<3>()[2] / 2;
        let d_projection = geglu_backward(f32s(projection), f32s(&grad), inner);
        let parents = ops.parents.iter().map(|p| p.as_ref().map(|node| node.id));
        register_grads(grads, parents, [(Some(d_projection), shape_of(projection))]);
    }
}

fn fused_geglu<C: FlexAutodiff>(projection: Tensor<3>) -> Tensor<3> {
    let [n, t, two_inner] = projection.dims();
    let projection = C::into_primitive(projection);
    let values = contiguous(projection.primitive().clone());
    let out = geglu(f32s(&values), two_inner / 2);
    let out = FlexTensor::from_data(TensorData::new(out, [n, t, two_inner / 2]));
    let state = || GegluState { projection: values };
    C::from_primitive(record::<C, _, 1>(FusedGeglu, [projection.node()], state, out))
}

/// `out` as the result of the node `op` on `parents`: recorded with its backward state
/// (`state` is only called then) when a parent is tracked, a plain untracked result otherwise.
/// The one way every node here joins the graph.
fn record<C: FlexAutodiff, O: Backward<Flex, N>, const N: usize>(
    op: O,
    parents: [NodeGuard; N],
    state: impl FnOnce() -> O::State,
    out: FlexTensor,
) -> FlexAutodiffTensor {
    match op.prepare::<C>(parents).compute_bound().stateful() {
        OpsKind::Tracked(prep) => prep.finish(state(), out),
        OpsKind::UnTracked(prep) => prep.finish(out),
    }
}

/// Registers each computed gradient (`values`, shaped as given) for its parent node, where the
/// parent is tracked (`Some` id): the one way every node here hands its gradients back.
fn register_grads(
    grads: &mut Gradients,
    parents: impl IntoIterator<Item = Option<NodeId>>,
    gradients: impl IntoIterator<Item = (Option<Vec<f32>>, Shape)>,
) {
    for (parent, (values, shape)) in parents.into_iter().zip(gradients) {
        if let (Some(id), Some(values)) = (parent, values) {
            grads.register::<Flex>(id, FlexTensor::from_data(TensorData::new(values, shape)));
        }
    }
}

/// The shape of a flex tensor.
fn shape_of(t: &FlexTensor) -> Shape {
    t.layout().shape().clone()
}

/// `t` with contiguous storage (a copy only when it is a strided view).
fn contiguous(t: FlexTensor) -> FlexTensor {
    if t.as_slice::<f32>().is_some() { t } else { t.to_contiguous() }
}

/// The values of a contiguous f32 tensor.
fn f32s(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>().expect("a contiguous f32 tensor (made so by `contiguous`)")
}
