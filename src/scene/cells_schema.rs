//! The cell scene file as it is written (`[fluid]`, `[flow]`, `[[cells]]`, `[numerics]`,
//! `[output]`): the TOML sections with their values and spans, before validation
//! ([`super::cells::parse`] turns them into a [`super::cells::CellScene`]).

use serde::Deserialize;
use toml::Spanned;

use super::GpuFlag;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct File {
    pub(super) fluid: Option<FluidSection>,
    pub(super) flow: Option<FlowSection>,
    pub(super) cells: Option<Vec<CellSection>>,
    pub(super) numerics: Option<NumericsSection>,
    pub(super) output: Option<OutputSection>,
    /// `[[walls]]` ([`super::walls`]).
    pub(super) walls: Option<Vec<WallSection>>,
    /// `[units]` ([`super::units`]).
    pub(super) units: Option<UnitsSection>,
    /// `mobo dpd`'s section: the same file runs both ways (its `[dpd.from_cells]` maps these
    /// cells into the DPD fluid); `mobo run` does not read it.
    #[serde(rename = "dpd")]
    pub(super) _dpd: Option<serde::de::IgnoredAny>,
}

/// `[units]` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct UnitsSection {
    pub(super) system: Spanned<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FluidSection {
    pub(super) viscosity: Spanned<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FlowSection {
    pub(super) kind: Spanned<String>,
    pub(super) rate: Option<Spanned<f64>>,
    pub(super) speed: Option<Spanned<f64>>,
    pub(super) radius: Option<Spanned<f64>>,
    pub(super) frame: Option<Spanned<String>>,
    pub(super) flow_rate: Option<Spanned<f64>>,
    pub(super) mean_speed: Option<Spanned<f64>>,
    pub(super) pressure_gradient: Option<Spanned<f64>>,
    pub(super) recycle: Option<Spanned<bool>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CellSection {
    pub(super) shape: Spanned<String>,
    pub(super) radius: Option<Spanned<f64>>,
    pub(super) center: Option<Spanned<[f64; 3]>>,
    pub(super) axes: Option<Spanned<[f64; 3]>>,
    pub(super) reduced_volume: Option<Spanned<f64>>,
    pub(super) orientation: Option<Spanned<[f64; 4]>>,
    pub(super) bending_modulus: Option<Spanned<f64>>,
    pub(super) shear_modulus: Option<Spanned<f64>>,
    pub(super) skalak_c: Option<Spanned<f64>>,
    pub(super) prestress: Option<Spanned<f64>>,
    pub(super) membrane: Option<Spanned<String>>,
    pub(super) elastic_law: Option<Spanned<String>>,
    pub(super) viscosity_ratio: Option<Spanned<f64>>,
    pub(super) force: Option<Spanned<[f64; 3]>>,
    pub(super) count: Option<Spanned<usize>>,
    pub(super) placement: Option<Spanned<String>>,
    pub(super) spacing: Option<Spanned<f64>>,
    pub(super) region: Option<Spanned<[[f64; 3]; 2]>>,
    pub(super) seed: Option<u64>,
    pub(super) volume_fraction: Option<Spanned<f64>>,
    pub(super) min_gap: Option<Spanned<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct NumericsSection {
    pub(super) order: Option<Spanned<usize>>,
    pub(super) upsample: Option<Spanned<usize>>,
    pub(super) fmm_digits: Option<Spanned<u32>>,
    pub(super) gmres_tol: Option<Spanned<f64>>,
    pub(super) dt: Option<Spanned<f64>>,
    pub(super) t_end: Option<Spanned<f64>>,
    pub(super) scheme: Option<Spanned<String>>,
    pub(super) elasticity: Option<Spanned<String>>,
    pub(super) grid: Option<Spanned<String>>,
    pub(super) adaptive_dt: Option<bool>,
    pub(super) far_side_split: Option<bool>,
    pub(super) operator_storage: Option<Spanned<String>>,
    pub(super) preconditioner: Option<Spanned<String>>,
    pub(super) preconditioner_rebuild_after: Option<Spanned<u64>>,
    pub(super) dt_tolerance: Option<Spanned<f64>>,
    pub(super) dt_min: Option<Spanned<f64>>,
    pub(super) dt_max: Option<Spanned<f64>>,
    pub(super) repulsion_range: Option<Spanned<f64>>,
    pub(super) repulsion_strength: Option<Spanned<f64>>,
    pub(super) rebalance_every: Option<Spanned<u64>>,
    pub(super) max_imbalance: Option<Spanned<f64>>,
    pub(super) coupling: Option<Spanned<String>>,
    pub(super) contact_distance: Option<Spanned<f64>>,
    pub(super) implicit_zone: Option<Spanned<f64>>,
    pub(super) start_up_passes: Option<Spanned<u64>>,
    pub(super) start_up_anderson_depth: Option<Spanned<u64>>,
    pub(super) gpu: Option<Spanned<GpuFlag>>,
    pub(super) wall_solve: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct OutputSection {
    pub(super) every: Option<Spanned<u64>>,
    pub(super) npy: Option<bool>,
    pub(super) vtk: Option<bool>,
    pub(super) hdf5: Option<bool>,
    pub(super) mesh_subdivisions: Option<Spanned<u32>>,
    pub(super) checkpoint_every: Option<Spanned<u64>>,
    pub(super) velocity_plane: Option<super::velocity_plane::PlaneSection>,
}

/// Where a scene's text comes from: what its messages cite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Origin {
    /// A file the user wrote: `[[cells]]` entries by number (from 1) and line.
    File,
    /// The text of a [`super::spec::SceneSpec`]: its `cells[k]` (from 0), no lines (the user
    /// never saw the text).
    Spec,
}

/// A `[[walls]]` entry as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct WallSection {
    pub(super) kind: Spanned<String>,
    pub(super) shape: Spanned<String>,
    pub(super) radius: Option<Spanned<f64>>,
    pub(super) axes: Option<Spanned<[f64; 3]>>,
    pub(super) length: Option<Spanned<f64>>,
    pub(super) width: Option<Spanned<f64>>,
    pub(super) height: Option<Spanned<f64>>,
    pub(super) center: Option<Spanned<[f64; 3]>>,
    pub(super) order: Option<Spanned<usize>>,
    pub(super) angular_velocity: Option<Spanned<[f64; 3]>>,
    pub(super) positions: Option<Spanned<String>>,
    pub(super) velocity: Option<Spanned<String>>,
    pub(super) normal: Option<Spanned<[f64; 3]>>,
}
