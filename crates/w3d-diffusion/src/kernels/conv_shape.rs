//! The shape of a square-kernel convolution, shared by the convolution kernels
//! ([`crate::kernels::conv`] for training, [`crate::kernels::bf16`] for bf16 products).

/// Shape of a square-kernel convolution with zero padding, images `[batch, c_in, height,
/// width]`, weight `[c_out, c_in, kernel, kernel]` (PyTorch's layouts).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ConvShape {
    /// Images.
    pub batch: usize,
    /// Input channels.
    pub c_in: usize,
    /// Input height in pixels.
    pub height: usize,
    /// Input width in pixels.
    pub width: usize,
    /// Output channels.
    pub c_out: usize,
    /// Kernel side in pixels.
    pub kernel: usize,
    /// Stride in pixels (at least 1).
    pub stride: usize,
    /// Zero padding on each side in pixels.
    pub padding: usize,
}

impl ConvShape {
    /// Output height and width (PyTorch's `(h + 2p − k) / s + 1`); `None` when the kernel does
    /// not fit the padded image, or the stride or kernel is 0.
    pub(crate) fn output(&self) -> Option<(usize, usize)> {
        if self.stride == 0 || self.kernel == 0 {
            return None;
        }
        let side = |n: usize| (n + 2 * self.padding).checked_sub(self.kernel).map(|r| r / self.stride + 1);
        Some((side(self.height)?, side(self.width)?))
    }

    /// Output pixels per image (0 when the kernel does not fit).
    #[cfg_attr(not(feature = "train"), allow(dead_code))]
    pub(crate) fn out_pixels(&self) -> usize {
        self.output().map_or(0, |(h, w)| h * w)
    }

    /// Rows of the column matrix: `c · k²`.
    #[cfg_attr(not(feature = "train"), allow(dead_code))]
    pub(crate) fn patch(&self) -> usize {
        self.c_in * self.kernel * self.kernel
    }

    /// Whether the column matrix is the image itself (1×1, stride 1, no padding).
    #[cfg_attr(not(feature = "train"), allow(dead_code))]
    pub(crate) fn pointwise(&self) -> bool {
        self.kernel == 1 && self.stride == 1 && self.padding == 0
    }

    /// Whether the output has the input's size with stride 1 (`k = 2p + 1`: the UNet's and
    /// the VAE's 3×3 and 1×1 convolutions), so that each kernel tap's im2col row is the input
    /// plane shifted by a fixed offset.
    pub(crate) fn same_size(&self) -> bool {
        self.stride == 1 && self.kernel == 2 * self.padding + 1
    }
}
