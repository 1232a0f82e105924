//! Single-threaded `f32` GEMM on strided views of plain slices, through the `gemm` crate: the
//! building block of the crate's CPU kernels ([`crate::kernels::attention`], [`crate::kernels::conv`]),
//! which parallelise over their own work units.

/// A read-only strided matrix view: element `(r, c)` is `data[r·row_stride + c·col_stride]`.
#[derive(Clone, Copy)]
pub(crate) struct MatRef<'a> {
    pub data: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub row_stride: usize,
    pub col_stride: usize,
}

/// A writable strided matrix view, laid out as [`MatRef`].
pub(crate) struct MatMut<'a> {
    pub data: &'a mut [f32],
    pub rows: usize,
    pub cols: usize,
    pub row_stride: usize,
    pub col_stride: usize,
}

/// Index of the last element a strided view touches, `None` for an empty view.
fn last_index(rows: usize, cols: usize, row_stride: usize, col_stride: usize) -> Option<usize> {
    (rows > 0 && cols > 0).then(|| (rows - 1) * row_stride + (cols - 1) * col_stride)
}

/// `dst = beta·lhs·rhs` (or `dst += beta·lhs·rhs` with `accumulate`), single-threaded (the
/// caller parallelises over work units). A safe wrapper: the views' extents are checked
/// against their slices before the `gemm` crate reads or writes through raw pointers.
pub(crate) fn gemm_f32(dst: MatMut<'_>, lhs: MatRef<'_>, rhs: MatRef<'_>, accumulate: bool, beta: f32) {
    assert_eq!(lhs.rows, dst.rows, "gemm: lhs rows");
    assert_eq!(rhs.cols, dst.cols, "gemm: rhs cols");
    assert_eq!(lhs.cols, rhs.rows, "gemm: inner dimension");
    let Some(dst_last) = last_index(dst.rows, dst.cols, dst.row_stride, dst.col_stride) else { return };
    assert!(dst_last < dst.data.len(), "gemm: destination view out of bounds");
    if let Some(last) = last_index(lhs.rows, lhs.cols, lhs.row_stride, lhs.col_stride) {
        assert!(last < lhs.data.len(), "gemm: lhs view out of bounds");
    }
    if let Some(last) = last_index(rhs.rows, rhs.cols, rhs.row_stride, rhs.col_stride) {
        assert!(last < rhs.data.len(), "gemm: rhs view out of bounds");
    }
    let stride = |s: usize| isize::try_from(s).expect("gemm: stride fits isize");
    // SAFETY: every element the call reads or writes lies in its view (checked above against
    // the slices' lengths); `dst` is a unique borrow, so it aliases neither `lhs` nor `rhs`;
    // with an inner dimension of 0 and `accumulate` false the crate writes `dst` without
    // reading it.
    #[allow(unsafe_code)]
    unsafe {
        gemm::gemm(
            dst.rows,
            dst.cols,
            lhs.cols,
            dst.data.as_mut_ptr(),
            stride(dst.col_stride),
            stride(dst.row_stride),
            accumulate,
            lhs.data.as_ptr(),
            stride(lhs.col_stride),
            stride(lhs.row_stride),
            rhs.data.as_ptr(),
            stride(rhs.col_stride),
            stride(rhs.row_stride),
            1.0,
            beta,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}
