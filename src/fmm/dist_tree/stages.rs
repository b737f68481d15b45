//! Binomial trees over the ranks that take part in one top box's exchange: the reduction of
//! its sharers' partial expansions to the owner, and the broadcast of the sum from the owner
//! to the ranks whose lists use it, each in `⌈log₂ m⌉` stages for `m` participants.
//!
//! Participants are numbered `0..m` (the owner is 0). **Reduction**, stage `j`: a participant
//! whose index has its lowest set bit at `j` sends its running sum to `i − 2ʲ`, which adds it
//! to its own; one with no set bit below `j + 1` receives from `i + 2ʲ` if that exists. After
//! `⌈log₂ m⌉` stages participant 0 holds the sum of all, and no participant has sent more than
//! once or received more than `⌈log₂ m⌉` times: the owner of a box shared by `m` ranks takes
//! `⌈log₂ m⌉` messages instead of `m − 1`, the hypercube reduction of PVFMM (Lashuk et al.,
//! SC'09) and MOBO (Rahimian et al., SC'10). **Broadcast**: the reduction's stages reversed,
//! senders and receivers swapped; participant 0 sends `⌈log₂ m⌉` times instead of `m − 1`,
//! every other participant receives once.

/// What one participant does at one stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Partner {
    /// Send to this participant.
    SendTo(usize),
    /// Receive from this participant.
    ReceiveFrom(usize),
}

/// Stages of a tree over `m` participants: `⌈log₂ m⌉` (0 for one or none).
pub fn stage_count(m: usize) -> usize {
    if m <= 1 {
        0
    } else {
        (usize::BITS - (m - 1).leading_zeros()) as usize
    }
}

/// Participant `i`'s part in stage `j` of the reduction to participant 0 over `m`.
pub fn reduce_partner(i: usize, m: usize, j: usize) -> Option<Partner> {
    if i >= m || j >= stage_count(m) {
        return None;
    }
    let step = 1usize << j;
    if !i.is_multiple_of(step) {
        // Sent its sum at an earlier stage.
        return None;
    }
    if (i / step) % 2 == 1 {
        Some(Partner::SendTo(i - step))
    } else if i + step < m {
        Some(Partner::ReceiveFrom(i + step))
    } else {
        None
    }
}

/// Participant `i`'s part in stage `j` of the broadcast from participant 0 over `m`.
pub fn broadcast_partner(i: usize, m: usize, j: usize) -> Option<Partner> {
    let s = stage_count(m);
    if j >= s {
        return None;
    }
    reduce_partner(i, m, s - 1 - j).map(|p| match p {
        Partner::SendTo(x) => Partner::ReceiveFrom(x),
        Partner::ReceiveFrom(x) => Partner::SendTo(x),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plays a schedule over `m` participants holding `start`: every send must be matched by
    /// the partner's receive at the same stage. Returns the values held at the end (a receiver
    /// adds what it gets, or takes it) and the messages each sent and received.
    fn play(
        m: usize,
        partner: fn(usize, usize, usize) -> Option<Partner>,
        start: &[u128],
        add: bool,
    ) -> (Vec<u128>, Vec<usize>, Vec<usize>) {
        let mut v = start.to_vec();
        let (mut sent, mut got) = (vec![0; m], vec![0; m]);
        for j in 0..stage_count(m) {
            let before = v.clone();
            for i in 0..m {
                match partner(i, m, j) {
                    Some(Partner::SendTo(t)) => {
                        assert_eq!(
                            partner(t, m, j),
                            Some(Partner::ReceiveFrom(i)),
                            "m {m} j {j}"
                        );
                        sent[i] += 1;
                    }
                    Some(Partner::ReceiveFrom(f)) => {
                        assert_eq!(partner(f, m, j), Some(Partner::SendTo(i)), "m {m} j {j}");
                        got[i] += 1;
                        v[i] = if add { v[i] + before[f] } else { before[f] };
                    }
                    None => {}
                }
            }
        }
        (v, sent, got)
    }

    #[test]
    fn stage_count_is_the_ceiling_of_log2() {
        let want = [0, 0, 1, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5];
        for (m, &s) in want.iter().enumerate() {
            assert_eq!(stage_count(m), s, "m = {m}");
        }
        assert_eq!(stage_count(1 << 20), 20);
        assert_eq!(stage_count((1 << 20) + 1), 21);
    }

    #[test]
    fn the_reduction_sums_every_participant_once_at_the_owner() {
        for m in 1..=128 {
            // One bit per participant: the owner's sum has every bit once (a value added twice
            // would carry into another bit).
            let start: Vec<u128> = (0..m).map(|i| 1u128 << i).collect();
            let (v, sent, got) = play(m, reduce_partner, &start, true);
            assert_eq!(v[0], start.iter().sum::<u128>(), "m = {m}");
            let s = stage_count(m);
            assert_eq!(sent[0], 0);
            assert_eq!(got[0], s, "m = {m}: the owner receives ⌈log₂ m⌉ messages");
            for i in 1..m {
                assert_eq!(sent[i], 1, "m = {m}, i = {i}: sends once");
                assert!(got[i] < s, "m = {m}, i = {i}");
            }
        }
    }

    #[test]
    fn the_broadcast_reaches_every_participant_once() {
        for m in 1..=128 {
            let mut start = vec![0u128; m];
            start[0] = 42;
            let (v, sent, got) = play(m, broadcast_partner, &start, false);
            assert!(v.iter().all(|&x| x == 42), "m = {m}: {v:?}");
            assert_eq!(got[0], 0);
            assert_eq!(sent[0], stage_count(m), "m = {m}");
            for i in 1..m {
                assert_eq!(got[i], 1, "m = {m}, i = {i}: receives once");
                assert!(sent[i] < stage_count(m).max(1), "m = {m}, i = {i}");
            }
        }
    }
}
