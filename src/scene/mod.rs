//! Scene files (TOML): schema, validation with errors that name the file, line and key.
//!
//! [`cells`]: cell scenes for `mobo run` (fluid, flow, cells, numerics, output) and the
//! assembly decisions; [`brownian`]: the `[brownian]` section of `mobo brownian`.

pub mod brownian;
mod cell_groups;
mod cell_scene;
pub mod cells;
mod cells_schema;
pub mod dense_defaults;
pub mod dpd;
pub mod packing;
mod packing_report;
pub mod spec;
pub mod tube_flow;
pub mod units;
pub mod velocity_plane;
pub mod walls;

use std::path::{Path, PathBuf};

/// A scene error: the file, the place (line and column where known) and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{}{}: {message}", file.display(), place.map(|(l, c)| format!(":{l}:{c}")).unwrap_or_default())]
pub struct SceneError {
    /// The scene file.
    pub file: PathBuf,
    /// Line and column (1-based), if known.
    pub place: Option<(usize, usize)>,
    /// What is wrong.
    pub message: String,
}

impl SceneError {
    /// An error without a place.
    pub fn new(file: &Path, message: impl Into<String>) -> Self {
        SceneError {
            file: file.to_path_buf(),
            place: None,
            message: message.into(),
        }
    }
}

/// Parse TOML text into `T`, turning parse and schema errors into [`SceneError`]s with the line.
pub fn parse_toml<T: serde::de::DeserializeOwned>(
    file: &Path,
    text: &str,
) -> Result<T, SceneError> {
    toml::from_str(text).map_err(|e| {
        let place = e.span().map(|s| line_col(text, s.start));
        SceneError {
            file: file.to_path_buf(),
            place,
            message: e.message().trim().to_string(),
        }
    })
}

/// 1-based line and column of a byte offset.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before
        .rfind('\n')
        .map_or(before.len(), |p| before.len() - p - 1)
        + 1;
    (line, col)
}

/// Read a file to a string, with the file name in the error.
pub fn read_scene_file(file: &Path) -> Result<String, SceneError> {
    std::fs::read_to_string(file).map_err(|e| SceneError::new(file, format!("cannot read: {e}")))
}

/// A scene's `gpu` key (`[numerics]`, `[brownian]`, `[dpd]`): `"auto"`, or a boolean.
#[derive(Debug, serde::Deserialize)]
#[serde(untagged)]
pub(crate) enum GpuFlag {
    Flag(bool),
    Word(String),
}

impl GpuFlag {
    /// The choice it names, or what is wrong with it.
    pub(crate) fn choice(&self) -> Result<crate::gpu::GpuChoice, String> {
        use crate::gpu::GpuChoice;
        match self {
            GpuFlag::Flag(true) => Ok(GpuChoice::On),
            GpuFlag::Flag(false) => Ok(GpuChoice::Off),
            GpuFlag::Word(w) if w == "auto" => Ok(GpuChoice::Auto),
            GpuFlag::Word(w) => Err(format!("must be \"auto\", true or false, got \"{w}\"")),
        }
    }
}
