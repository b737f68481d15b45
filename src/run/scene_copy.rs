//! The scene as a run keeps it: `DIR/scene.toml`, what `mobo run --resume DIR` reads again.
//!
//! The copy is the scene's text as given, except that a grid wall's files (`positions`,
//! `velocity`: `crate::scene::walls`) are copied into `DIR/walls/` and its names point there,
//! so that a resumed run reads the same wall wherever the scene and its files were.

use std::path::Path;

use super::error::CellRunError;
use crate::io::{write_atomic, IoError};
use crate::scene::cells::CellScene;

/// The folder of the output that holds the grid walls' files.
pub const WALL_FILES: &str = "walls";

/// Write `text` (the text `scene` was read from) as `out/name`, with every grid wall's files
/// copied to `out/walls/wall_K_KEY.npy` and named so in the copy.
pub fn write_scene_copy(
    scene: &CellScene,
    text: &str,
    out: &Path,
    name: &str,
) -> Result<(), CellRunError> {
    let mut edits = Vec::new();
    for (k, w) in scene.walls.iter().enumerate() {
        for f in &w.files {
            let copy = format!("{WALL_FILES}/wall_{k}_{}.npy", f.key);
            let bytes = std::fs::read(&f.path).map_err(|source| IoError::File {
                path: f.path.clone(),
                source,
            })?;
            let dir = out.join(WALL_FILES);
            std::fs::create_dir_all(&dir).map_err(|source| IoError::File {
                path: dir.clone(),
                source,
            })?;
            write_atomic(&out.join(&copy), &bytes)?;
            edits.push((f.span.clone(), format!("\"{copy}\"")));
        }
    }
    // From the end, so that the earlier spans stay where they are.
    edits.sort_by_key(|e| std::cmp::Reverse(e.0.start));
    let mut copy = text.to_string();
    for (span, name) in edits {
        copy.replace_range(span, &name);
    }
    write_atomic(&out.join(name), copy.as_bytes())?;
    Ok(())
}
