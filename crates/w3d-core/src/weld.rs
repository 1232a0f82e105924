//! Welding vertices by position: the position classes that `Mesh::merge_by_position` merges by
//! and that normals, the rasteriser and UV charting use to see through UV and colour seams.
//! Re-exported as `w3d_core::mesh::weld_by_position`.

use std::collections::HashMap;

/// For each vertex, the index of its position class: vertices with bit-identical
/// positions (−0 and +0 equal) share a class, and classes are numbered `0, 1, …` in order
/// of first appearance. `Mesh::merge_by_position` builds on it; the rasteriser uses it
/// to match edges across UV seams.
pub fn weld_by_position(positions: &[[f32; 3]]) -> Vec<u32> {
    let mut class_of: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    positions
        .iter()
        .map(|p| {
            let key = p.map(|v| if v == 0.0 { 0 } else { v.to_bits() });
            let next = class_of.len() as u32;
            *class_of.entry(key).or_insert(next)
        })
        .collect()
}
