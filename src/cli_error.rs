//! The errors of the `mobo` command line, shared by its subcommands.

#[derive(Debug, thiserror::Error)]
pub(crate) enum CliError {
    #[error("spherical harmonics: {0}")]
    Sph(#[from] mobo::sph_harmonics::SphError),
    #[error("invalid argument: {0}")]
    Arg(String),
    #[error("{0}")]
    Scene(#[from] mobo::scene::SceneError),
    #[error("{0}")]
    Io(#[from] mobo::io::IoError),
    #[error("{0}")]
    Fmm(#[from] mobo::fmm::FmmError),
    #[error("{0}")]
    Comm(#[from] mobo::comm::CommError),
    #[error("{0}")]
    Run(#[from] mobo::run::brownian::RunError),
    #[error("{0}")]
    CellRun(#[from] mobo::run::CellRunError),
    #[error("{0}")]
    Report(#[from] mobo::report::ReportError),
    #[error("{0}")]
    Dpd(#[from] mobo::run::dpd::DpdRunError),
    #[error("interrupted")]
    Interrupted,
    /// An error that every rank of an MPI run has and rank 0 reports: the other ranks exit
    /// quietly with status 0 (rank 0's non-zero status is the job's).
    #[error("reported by rank 0")]
    ReportedElsewhere,
}
