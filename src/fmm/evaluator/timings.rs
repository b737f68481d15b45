//! What one evaluation reports: the seconds of each phase and the communication.

/// Wall time of each phase of the last evaluation, in seconds (phases that run inside one
/// parallel loop are split by summed thread time).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FmmTimings {
    /// P2M: leaf sources at their upward check surfaces (thread time).
    pub p2m: f64,
    /// M2M and the upward fits of the non-leaf boxes (thread time).
    pub m2m: f64,
    /// M2L: forward FFTs of the upward densities and inverse FFTs into the check potentials.
    pub m2l_fft: f64,
    /// M2L: the Hadamard products summed over the V lists.
    pub m2l_hadamard: f64,
    /// P2L: X-list sources at the downward check surfaces.
    pub p2l: f64,
    /// L2L and the downward fits.
    pub l2l: f64,
    /// L2P: downward equivalent densities at the leaves' targets (thread time).
    pub l2p: f64,
    /// M2P: W-list upward equivalent densities at the leaves' targets (thread time).
    pub m2p: f64,
    /// The near-field pass ([`crate::fmm::near_field`]): wall seconds of its backend (on the GPU:
    /// uploads, kernel and read-back included).
    pub p2p: f64,
    /// Whether the near field ran beside the CPU's far field (a GPU backend).
    pub near_concurrent: bool,
    /// Wall seconds of the CPU's far field from the ghost exchange on (top of the upward pass,
    /// M2L, downward pass, L2P, M2P): with a concurrent near field, `total` is about
    /// `max(p2p, far_wall)` plus the rest, rather than their sum.
    pub far_wall: f64,
    /// Wall seconds of the whole evaluation, communication included.
    pub total: f64,
}

impl FmmTimings {
    /// Add another evaluation's phases to these (totals over several evaluations; the flag is
    /// set if either ran its near field concurrently).
    pub fn accumulate(&mut self, other: &FmmTimings) {
        self.p2m += other.p2m;
        self.m2m += other.m2m;
        self.m2l_fft += other.m2l_fft;
        self.m2l_hadamard += other.m2l_hadamard;
        self.p2l += other.p2l;
        self.l2l += other.l2l;
        self.l2p += other.l2p;
        self.m2p += other.m2p;
        self.p2p += other.p2p;
        self.near_concurrent |= other.near_concurrent;
        self.far_wall += other.far_wall;
        self.total += other.total;
    }

    /// The phases by name, as `mobo fmm`'s JSON and `summary.json` list them.
    pub fn phases(&self) -> [(&'static str, f64); 9] {
        [
            ("p2m", self.p2m),
            ("m2m", self.m2m),
            ("m2l_fft", self.m2l_fft),
            ("m2l_hadamard", self.m2l_hadamard),
            ("p2l", self.p2l),
            ("l2l", self.l2l),
            ("l2p", self.l2p),
            ("m2p", self.m2p),
            ("p2p", self.p2p),
        ]
    }
}

/// Communication of the last evaluation on this rank.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct FmmComm {
    /// Number of ranks.
    pub ranks: usize,
    /// Bytes this rank sent to other ranks during the evaluation (both parts below).
    pub bytes_sent: u64,
    /// Of these, the locally essential tree (ghost boxes' expansions and leaf densities, point
    /// to point to neighbouring ranks) and the routing of densities and results between the
    /// caller's ranks and the owners: all but the top of the tree.
    pub let_bytes_sent: u64,
    /// Bytes of top-box expansions this rank received: partial sums in the stages of the
    /// reduction to the owners, and whole expansions in the stages of the broadcast (those its
    /// lists use, and those it forwards; `8 · ne` per box; see [`crate::fmm::dist_tree`]).
    pub top_bytes_received: u64,
    /// Messages this rank sent to other ranks during the evaluation
    /// ([`crate::comm::Communicator::messages_sent`]).
    pub messages_sent: u64,
    /// Seconds spent in communication (included in the phase total).
    pub seconds: f64,
}
