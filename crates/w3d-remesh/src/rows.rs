//! Per-vertex rows that the remesh ops carry through topology changes.

/// Per-vertex data that the remesh ops move around: a position plus any number of other
/// columns (optimizer state, colours, targets …).
///
/// Every op treats **all** columns alike (reference part A.9): a split appends the mean of
/// the two endpoint rows, a collapse overwrites the surviving row with the mean of the two
/// rows, a pack keeps a subset of rows in order. `Vec<[f32; 3]>` implements it for plain
/// positions.
pub trait VertexRows {
    /// The positions (one per row).
    fn positions(&self) -> &[[f32; 3]];

    /// Sets the position of row `i` (used to pin boundary vertices after a collapse).
    fn set_position(&mut self, i: usize, p: [f32; 3]);

    /// Row `dst` ← mean of rows `a` and `b`, all columns (`dst` may equal `a` or `b`).
    fn set_mean(&mut self, dst: usize, a: usize, b: usize);

    /// Appends a row equal to the mean of rows `a` and `b`, all columns.
    fn push_mean(&mut self, a: usize, b: usize);

    /// Keeps only the rows `keep[0], keep[1], …` (strictly increasing old indices), in that
    /// order.
    fn retain_rows(&mut self, keep: &[u32]);

    /// Number of rows.
    fn len(&self) -> usize {
        self.positions().len()
    }

    /// Whether there are no rows.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Mean of two 3-vectors.
pub(crate) fn mean3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [(a[0] + b[0]) * 0.5, (a[1] + b[1]) * 0.5, (a[2] + b[2]) * 0.5]
}

/// Keeps `keep[i]`-th elements of `values` in order (strictly increasing indices).
pub(crate) fn retain_indices<T: Copy>(values: &mut Vec<T>, keep: &[u32]) {
    for (new, &old) in keep.iter().enumerate() {
        values[new] = values[old as usize];
    }
    values.truncate(keep.len());
}

impl VertexRows for Vec<[f32; 3]> {
    fn positions(&self) -> &[[f32; 3]] {
        self
    }

    fn set_position(&mut self, i: usize, p: [f32; 3]) {
        self[i] = p;
    }

    fn set_mean(&mut self, dst: usize, a: usize, b: usize) {
        self[dst] = mean3(self[a], self[b]);
    }

    fn push_mean(&mut self, a: usize, b: usize) {
        self.push(mean3(self[a], self[b]));
    }

    fn retain_rows(&mut self, keep: &[u32]) {
        retain_indices(self, keep);
    }
}
