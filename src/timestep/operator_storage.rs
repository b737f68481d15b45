//! Where a cell's dense self-interaction operators live between their assembly and the GMRES
//! iterations of its step ([`OperatorStorage`]), and what each choice costs in memory.

/// How a cell keeps its self-interaction operators from the assembly to the GMRES iterations
/// of its step. All three give the same step to the GMRES tolerance (one RBC at `p = 12`, one
/// core: 0.14 / 0.14 / 2.7 s per step for grid / coefficients / matrix-free, measured on
/// different days; `benches/RESULTS.md`). The operators are reassembled at every step and read only within
/// the cell's own step, so the grid's live in the step engine (one per thread that steps):
/// it is the fastest and keeps nothing per cell. Coefficient space keeps its compressed
/// operators per cell (2.0 MB each at `p = 12`); matrix-free keeps none and needs no
/// dense buffer at all.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OperatorStorage {
    /// In coefficient space, `A_c = F A I` (`(3n_c)²` entries, 2.0 MB per operator at
    /// `p = 12`; [`crate::vesicle::coefficient_operator`]), applied as `P A x = I A_c F x`:
    /// the same step (the band-limited part of the solution, hence the new surface, is the
    /// same), 3.4× less memory than the full grid operator (1.9× less than the grid's rows),
    /// for a compression per assembly and two transforms per product.
    Coefficients,
    /// On the grid: `A = P F`, kept as the rows `P` over the density's coefficients
    /// (`3n × 3n_c` entries, 3.8 MB per operator at `p = 12`;
    /// [`crate::vesicle::layer::SelfInteraction::assemble_rows`]) and applied as `P (F x)` (the full `A`, `(3n)²`,
    /// without upsampling), in the buffers of the step engine the cell's step holds: the fast
    /// path, one operator (two with a viscosity contrast) per thread, none per cell.
    #[default]
    Grid,
    /// Not stored: every GMRES iteration applies `A` matrix-free, batched per latitude
    /// ([`crate::vesicle::layer::SelfInteraction::apply`]): memory linear in the points per cell, each product
    /// costing about half an assembly (for a thread that cannot hold one dense operator).
    MatrixFree,
}

impl OperatorStorage {
    /// Bytes of the operators one cell of order `p` keeps (`operators`: 1, or 2 with a
    /// viscosity contrast): none on the grid, whose operators the step engines hold (one set
    /// per thread, [`Self::bytes_per_thread`]).
    pub fn bytes_per_cell(self, p: usize, operators: usize) -> usize {
        let nc = (p + 1) * (p + 1) - 1;
        operators
            * 8
            * match self {
                OperatorStorage::Grid | OperatorStorage::MatrixFree => 0,
                OperatorStorage::Coefficients => 9 * nc * nc,
            }
    }

    /// Bytes of the operators a thread that steps cells holds: the grid operators' rows over
    /// coefficients (`3n × 3n_c`), also assembled there before the compression to coefficient
    /// space. This assumes upsampling (`q > p`, the default); without it the grid operators
    /// are the full `3n × 3n`, `n / n_c` (about 1.9) times more.
    pub fn bytes_per_thread(self, p: usize, operators: usize) -> usize {
        let (n, nc) = (2 * p * (p + 1), (p + 1) * (p + 1) - 1);
        match self {
            OperatorStorage::Grid => operators * 8 * 9 * n * nc,
            OperatorStorage::Coefficients => 8 * 9 * n * nc,
            OperatorStorage::MatrixFree => 0,
        }
    }

    /// The fastest storage whose operators for `cells` cells stepped by `threads` threads fit
    /// in `budget` bytes (`operators` per cell): the grid (which keeps none per cell, one set
    /// per thread), else coefficient space, else matrix-free.
    pub fn for_budget(
        cells: usize,
        threads: usize,
        p: usize,
        operators: usize,
        budget: u64,
    ) -> Self {
        [OperatorStorage::Grid, OperatorStorage::Coefficients]
            .into_iter()
            .find(|s| {
                (cells as u64) * (s.bytes_per_cell(p, operators) as u64)
                    + (threads as u64) * (s.bytes_per_thread(p, operators) as u64)
                    <= budget
            })
            .unwrap_or(OperatorStorage::MatrixFree)
    }
}
