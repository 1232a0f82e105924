//! Minimum s-t cut by the Boykov–Kolmogorov augmenting-path algorithm ("An experimental
//! comparison of min-cut/max-flow algorithms for energy minimization in vision", PAMI 2004),
//! written for this crate: two search trees (one from the source, one from the sink) grow
//! towards each other, a path found where they meet is augmented, and the nodes the
//! augmentation cut off are re-attached ("adopted") or freed. Trees are reused between
//! augmentations, which is what makes it fast on image grids.
//!
//! Capacities are integers, so every residual update is exact.

/// Parent marker: the node hangs directly off its terminal.
const TERMINAL: u32 = u32::MAX;
/// Parent marker: the node lost its parent in the last augmentation.
const ORPHAN: u32 = u32::MAX - 1;
/// Parent marker: the node belongs to no tree.
const NONE: u32 = u32::MAX - 2;

const FREE: u8 = 0;
const SOURCE: u8 = 1;
const SINK: u8 = 2;

/// A graph with terminal links (source → node, node → sink) and pairs of opposite arcs
/// between nodes; [`Graph::max_flow`] computes the minimum cut.
#[derive(Debug, Clone)]
pub struct Graph {
    /// Per node: residual source capacity minus residual sink capacity.
    terminal: Vec<i64>,
    /// Per arc: the node it points to.
    head: Vec<u32>,
    /// Per arc: residual capacity. Arc `a` and arc `a ^ 1` are opposite.
    residual: Vec<i64>,
    /// Per arc: the tail node (only until the arcs are sorted by tail).
    tail: Vec<u32>,
    /// Per node: its arcs are `order[first[n]..first[n + 1]]` after [`Graph::finalise`].
    first: Vec<u32>,
    order: Vec<u32>,
    flow: i64,
}

impl Graph {
    /// A graph of `nodes` nodes and room for `edges` node–node edges.
    pub fn new(nodes: usize, edges: usize) -> Graph {
        Graph {
            terminal: vec![0; nodes],
            head: Vec::with_capacity(2 * edges),
            residual: Vec::with_capacity(2 * edges),
            tail: Vec::with_capacity(2 * edges),
            first: Vec::new(),
            order: Vec::new(),
            flow: 0,
        }
    }

    /// Number of nodes.
    pub fn nodes(&self) -> usize {
        self.terminal.len()
    }

    /// Adds capacity `source` on the source → `node` link and `sink` on `node` → sink (both
    /// non-negative). The part both links share is flow already: it is counted and removed.
    pub fn add_terminal(&mut self, node: usize, source: i64, sink: i64) {
        debug_assert!(source >= 0 && sink >= 0);
        self.flow += source.min(sink);
        self.terminal[node] += source - sink;
    }

    /// Adds an edge between `a` and `b` with capacity `ab` from `a` to `b` and `ba` back.
    pub fn add_edge(&mut self, a: usize, b: usize, ab: i64, ba: i64) {
        debug_assert!(a != b && ab >= 0 && ba >= 0);
        self.head.push(b as u32);
        self.tail.push(a as u32);
        self.residual.push(ab);
        self.head.push(a as u32);
        self.tail.push(b as u32);
        self.residual.push(ba);
    }

    /// Groups the arcs by tail node (a counting sort; arcs keep their ids).
    fn finalise(&mut self) {
        let n = self.nodes();
        let mut first = vec![0u32; n + 1];
        for &t in &self.tail {
            first[t as usize + 1] += 1;
        }
        for i in 0..n {
            first[i + 1] += first[i];
        }
        let mut fill = first.clone();
        let mut order = vec![0u32; self.tail.len()];
        for (arc, &t) in self.tail.iter().enumerate() {
            order[fill[t as usize] as usize] = arc as u32;
            fill[t as usize] += 1;
        }
        self.first = first;
        self.order = order;
    }

    /// Computes the maximum flow (= the capacity of the minimum cut). Returns the flow and,
    /// per node, whether it lies on the source side of a minimum cut.
    pub fn max_flow(mut self) -> (i64, Vec<bool>) {
        self.finalise();
        let n = self.nodes();
        let mut tree = vec![FREE; n];
        let mut parent = vec![NONE; n];
        let mut stamp = vec![0u32; n];
        let mut dist = vec![0u32; n];
        let mut active = std::collections::VecDeque::new();
        let mut queued = vec![false; n];
        for i in 0..n {
            if self.terminal[i] != 0 {
                tree[i] = if self.terminal[i] > 0 { SOURCE } else { SINK };
                parent[i] = TERMINAL;
                dist[i] = 1;
                active.push_back(i as u32);
                queued[i] = true;
            }
        }
        let mut time = 0u32;
        let mut orphans: std::collections::VecDeque<u32> = std::collections::VecDeque::new();

        while let Some(p) = active.pop_front() {
            let p = p as usize;
            queued[p] = false;
            if parent[p] == NONE {
                continue; // freed since it was queued
            }
            // Grow: look for an arc into the other tree.
            let mut meeting = None;
            for k in self.first[p]..self.first[p + 1] {
                let a = self.order[k as usize] as usize;
                let q = self.head[a] as usize;
                let (open, tree_p) =
                    if tree[p] == SOURCE { (self.residual[a] > 0, SOURCE) } else { (self.residual[a ^ 1] > 0, SINK) };
                if !open {
                    continue;
                }
                if tree[q] == FREE {
                    tree[q] = tree_p;
                    parent[q] = (a ^ 1) as u32; // arc q → p
                    stamp[q] = stamp[p];
                    dist[q] = dist[p] + 1;
                    if !queued[q] {
                        queued[q] = true;
                        active.push_back(q as u32);
                    }
                } else if tree[q] != tree_p {
                    // The trees touch: the path's middle arc goes from the source tree to the
                    // sink tree.
                    meeting = Some(if tree_p == SOURCE { a } else { a ^ 1 });
                    break;
                } else if stamp[q] <= stamp[p] && dist[q] > dist[p] {
                    // A shorter way to the terminal for q (the BK heuristic).
                    parent[q] = (a ^ 1) as u32;
                    stamp[q] = stamp[p];
                    dist[q] = dist[p] + 1;
                }
            }
            let Some(middle) = meeting else { continue };
            // p may have more paths to give: look at it again later.
            if !queued[p] {
                queued[p] = true;
                active.push_back(p as u32);
            }
            time += 1;

            // Augment along source … s_node → t_node … sink.
            let s_node = self.head[middle ^ 1] as usize;
            let t_node = self.head[middle] as usize;
            let mut bottleneck = self.residual[middle];
            let mut i = s_node;
            while parent[i] != TERMINAL {
                let a = parent[i] as usize;
                bottleneck = bottleneck.min(self.residual[a ^ 1]);
                i = self.head[a] as usize;
            }
            bottleneck = bottleneck.min(self.terminal[i]);
            let mut i = t_node;
            while parent[i] != TERMINAL {
                let a = parent[i] as usize;
                bottleneck = bottleneck.min(self.residual[a]);
                i = self.head[a] as usize;
            }
            bottleneck = bottleneck.min(-self.terminal[i]);

            self.residual[middle] -= bottleneck;
            self.residual[middle ^ 1] += bottleneck;
            let mut i = s_node;
            while parent[i] != TERMINAL {
                let a = parent[i] as usize;
                self.residual[a] += bottleneck;
                self.residual[a ^ 1] -= bottleneck;
                let next = self.head[a] as usize;
                if self.residual[a ^ 1] == 0 {
                    parent[i] = ORPHAN;
                    orphans.push_back(i as u32);
                }
                i = next;
            }
            self.terminal[i] -= bottleneck;
            if self.terminal[i] == 0 {
                parent[i] = ORPHAN;
                orphans.push_back(i as u32);
            }
            let mut i = t_node;
            while parent[i] != TERMINAL {
                let a = parent[i] as usize;
                self.residual[a ^ 1] += bottleneck;
                self.residual[a] -= bottleneck;
                let next = self.head[a] as usize;
                if self.residual[a] == 0 {
                    parent[i] = ORPHAN;
                    orphans.push_back(i as u32);
                }
                i = next;
            }
            self.terminal[i] += bottleneck;
            if self.terminal[i] == 0 {
                parent[i] = ORPHAN;
                orphans.push_back(i as u32);
            }
            self.flow += bottleneck;

            // Adopt: find each orphan a new parent in its own tree, or free it.
            while let Some(o) = orphans.pop_front() {
                let o = o as usize;
                let side = tree[o];
                let mut best: Option<(u32, u32)> = None; // (arc, distance)
                for k in self.first[o]..self.first[o + 1] {
                    let a0 = self.order[k as usize] as usize;
                    let j0 = self.head[a0] as usize;
                    if tree[j0] != side {
                        continue;
                    }
                    // Capacity from the candidate parent towards o (source tree) or from o
                    // towards it (sink tree).
                    let open = if side == SOURCE { self.residual[a0 ^ 1] > 0 } else { self.residual[a0] > 0 };
                    if !open {
                        continue;
                    }
                    // Does j0 still reach the terminal?
                    let mut j = j0;
                    let mut d = 0u32;
                    let reaches = loop {
                        if stamp[j] == time {
                            d += dist[j];
                            break true;
                        }
                        let a = parent[j];
                        d += 1;
                        if a == TERMINAL {
                            stamp[j] = time;
                            dist[j] = 1;
                            break true;
                        }
                        if a == ORPHAN || a == NONE {
                            break false;
                        }
                        j = self.head[a as usize] as usize;
                    };
                    if !reaches {
                        continue;
                    }
                    if best.is_none_or(|(_, bd)| d < bd) {
                        best = Some((a0 as u32, d));
                    }
                    // Stamp the path just walked with its distances.
                    let mut j = j0;
                    let mut dd = d;
                    while stamp[j] != time {
                        stamp[j] = time;
                        dist[j] = dd;
                        dd = dd.saturating_sub(1);
                        j = self.head[parent[j] as usize] as usize;
                    }
                }
                if let Some((a, d)) = best {
                    parent[o] = a;
                    stamp[o] = time;
                    dist[o] = d + 1;
                    continue;
                }
                // No parent: o leaves its tree. Its neighbours that could feed it become
                // active; its children become orphans.
                for k in self.first[o]..self.first[o + 1] {
                    let a0 = self.order[k as usize] as usize;
                    let j = self.head[a0] as usize;
                    if tree[j] != side {
                        continue;
                    }
                    let pa = parent[j];
                    if pa == NONE {
                        continue;
                    }
                    let open = if side == SOURCE { self.residual[a0 ^ 1] > 0 } else { self.residual[a0] > 0 };
                    if open && !queued[j] {
                        queued[j] = true;
                        active.push_back(j as u32);
                    }
                    if pa != TERMINAL && pa != ORPHAN && self.head[pa as usize] as usize == o {
                        parent[j] = ORPHAN;
                        orphans.push_back(j as u32);
                    }
                }
                tree[o] = FREE;
                parent[o] = NONE;
            }
        }
        let source_side = (0..n).map(|i| tree[i] == SOURCE && parent[i] != NONE).collect();
        (self.flow, source_side)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Max flow by shortest augmenting paths on a dense capacity matrix (node 0 = source,
    /// node 1 = sink): slow and obviously right, for comparison.
    fn edmonds_karp(cap: &mut [Vec<i64>]) -> i64 {
        let n = cap.len();
        let mut flow = 0;
        loop {
            let mut prev = vec![usize::MAX; n];
            prev[0] = 0;
            let mut queue = std::collections::VecDeque::from([0usize]);
            while let Some(u) = queue.pop_front() {
                for v in 0..n {
                    if prev[v] == usize::MAX && cap[u][v] > 0 {
                        prev[v] = u;
                        queue.push_back(v);
                    }
                }
            }
            if prev[1] == usize::MAX {
                return flow;
            }
            let mut b = i64::MAX;
            let mut v = 1;
            while v != 0 {
                b = b.min(cap[prev[v]][v]);
                v = prev[v];
            }
            let mut v = 1;
            while v != 0 {
                cap[prev[v]][v] -= b;
                cap[v][prev[v]] += b;
                v = prev[v];
            }
            flow += b;
        }
    }

    /// A small deterministic generator (SplitMix64).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
    }

    #[test]
    fn matches_edmonds_karp_on_random_graphs() {
        let mut rng = Rng(7);
        for case in 0..300 {
            let nodes = 2 + rng.below(14) as usize;
            let mut g = Graph::new(nodes, 40);
            // Dense matrix: 0 = source, 1 = sink, node i → matrix index i + 2.
            let mut cap = vec![vec![0i64; nodes + 2]; nodes + 2];
            for i in 0..nodes {
                let (s, t) = (rng.below(4) as i64 * rng.below(20) as i64, rng.below(4) as i64 * rng.below(20) as i64);
                g.add_terminal(i, s, t);
                cap[0][i + 2] += s;
                cap[i + 2][1] += t;
            }
            for _ in 0..rng.below(40) {
                let (a, b) = (rng.below(nodes as u64) as usize, rng.below(nodes as u64) as usize);
                if a == b {
                    continue;
                }
                let (ab, ba) = (rng.below(15) as i64, rng.below(15) as i64);
                g.add_edge(a, b, ab, ba);
                cap[a + 2][b + 2] += ab;
                cap[b + 2][a + 2] += ba;
            }
            let original = cap.clone();
            let expected = edmonds_karp(&mut cap);
            let (flow, side) = g.max_flow();
            assert_eq!(flow, expected, "case {case}");
            // The labelling is a cut of exactly that capacity.
            let on_source = |m: usize| m == 0 || (m >= 2 && side[m - 2]);
            let mut cut = 0;
            for (u, row) in original.iter().enumerate() {
                for (v, &c) in row.iter().enumerate() {
                    if on_source(u) && !on_source(v) && v != 0 {
                        cut += c;
                    }
                }
            }
            assert_eq!(cut, expected, "case {case}: the returned cut");
        }
    }

    #[test]
    fn grid_cut_follows_the_weak_edges() {
        // A 6×6 grid: the left three columns want the source, the right three the sink;
        // a cheap vertical seam between columns 2 and 3.
        let (w, h) = (6usize, 6usize);
        let mut g = Graph::new(w * h, 2 * w * h);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if x < 3 {
                    g.add_terminal(i, 5, 0)
                } else {
                    g.add_terminal(i, 0, 5)
                }
                if x + 1 < w {
                    let c = if x == 2 { 1 } else { 100 };
                    g.add_edge(i, i + 1, c, c);
                }
                if y + 1 < h {
                    g.add_edge(i, i + w, 100, 100);
                }
            }
        }
        let (flow, side) = g.max_flow();
        assert_eq!(flow, 6);
        for y in 0..h {
            for x in 0..w {
                assert_eq!(side[y * w + x], x < 3);
            }
        }
    }
}
