//! The U, V, W and X lists of the boxes a rank computes, found from keys by descent through
//! adjacent boxes (in key order, so a box gets the same lists on any number of ranks).

use super::*;

impl DistTree {
    /// Boxes adjacent to `near`, found by descent from the root through adjacent boxes down
    /// to `max_level`: `(boxes at max_level, leaves above it)`, each in key order.
    fn adjacent_boxes(&self, near: &BoxKey, max_level: u32) -> (Vec<usize>, Vec<usize>) {
        let (mut at_level, mut leaves) = (Vec::new(), Vec::new());
        let Some(&root) = self.index.get(&BoxKey::ROOT) else {
            return (at_level, leaves);
        };
        let mut stack = vec![root];
        while let Some(a) = stack.pop() {
            let bx = &self.boxes[a];
            if !bx.key.adjacent(near) {
                continue;
            }
            if bx.key.level == max_level {
                at_level.push(a);
            } else if bx.leaf {
                leaves.push(a);
            } else {
                stack.extend(&bx.children);
            }
        }
        at_level.sort_unstable();
        leaves.sort_unstable();
        (at_level, leaves)
    }

    /// The U, V, W, X lists of the boxes this rank computes.
    pub(super) fn interaction_lists(&self) -> Lists {
        let n = self.boxes.len();
        let mut l = Lists::empty(n);
        for t in 0..n {
            let tb = &self.boxes[t];
            if !self.computes_down(t) {
                continue;
            }
            let key = tb.key;
            if let Some(pk) = key.parent() {
                // V: children of the parent's colleagues not adjacent to t; X: leaves coarser
                // than t adjacent to its parent but not to t.
                let (colleagues, coarse) = self.adjacent_boxes(&pk, pk.level);
                for &c in &colleagues {
                    if self.boxes[c].leaf && !self.boxes[c].key.adjacent(&key) {
                        l.x[t].push(c);
                    }
                    for &ch in &self.boxes[c].children {
                        if !self.boxes[ch].key.adjacent(&key) {
                            l.v[t].push(ch);
                        }
                    }
                }
                l.x[t].extend(
                    coarse
                        .into_iter()
                        .filter(|&s| !self.boxes[s].key.adjacent(&key)),
                );
                l.x[t].sort_unstable();
            }
            if tb.leaf && tb.role == Role::Owned {
                // U: leaves adjacent to t; W: descendants of t's colleagues not adjacent to t
                // whose parents are.
                let (same, coarse) = self.adjacent_boxes(&key, key.level);
                l.u[t] = coarse;
                for c in same {
                    if self.boxes[c].leaf {
                        l.u[t].push(c);
                        continue;
                    }
                    let mut stack = self.boxes[c].children.clone();
                    while let Some(d) = stack.pop() {
                        let db = &self.boxes[d];
                        if !db.key.adjacent(&key) {
                            l.w[t].push(d);
                        } else if db.leaf {
                            l.u[t].push(d);
                        } else {
                            stack.extend(&db.children);
                        }
                    }
                }
                l.u[t].sort_unstable();
                l.w[t].sort_unstable();
            }
            l.v[t].sort_unstable();
        }
        l
    }
}
