//! The `[[cells]]` entries of a scene file expanded into cells: each entry's shape, membrane
//! and placement (one cell, a lattice, or random positions in a region), and the check that no
//! two cells overlap.

use std::path::Path;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use toml::Spanned;

use super::{line_col, SceneError};
use crate::vesicle::shapes::{Spheroid, Surface};
use crate::vesicle::skalak::ElasticLaw;

use super::cell_scene::{rotation, unit_shape, CellSpec, Shape, TubeWindow, WallSpec};
use super::cells_schema::{CellSection, Origin};
use super::packing::{
    cells_in_walls, fluid_volume, pack, window_volume, PackingReport, PackingRequest,
};
use crate::vesicle::surface_distance::{DistanceScratch, SurfaceDistance};

pub(super) type At<'a> = dyn Fn(std::ops::Range<usize>, String) -> SceneError + 'a;

pub(super) type Check<'a> = dyn Fn(&Spanned<f64>, &str) -> Result<f64, SceneError> + 'a;

/// The cells of `[[cells]]` entry `k`; random placement keeps clear of the `earlier` entries' cells.
#[allow(clippy::too_many_arguments)]
pub(super) fn cell_specs(
    c: &CellSection,
    k: usize,
    origin: Origin,
    earlier: &[CellSpec],
    at: &At,
    positive: &Check,
    finite: &Check,
    text: &str,
    order: usize,
    walls: &[WallSpec],
    window: Option<&TubeWindow>,
    packings: &mut Vec<PackingReport>,
) -> Result<Vec<CellSpec>, SceneError> {
    let key = |name: &str| match origin {
        Origin::File => format!("[[cells]] #{} {name}", k + 1),
        Origin::Spec => format!("cells[{k}].{name}"),
    };
    let shape = match c.shape.get_ref().as_str() {
        "sphere" => Shape::Sphere,
        "rbc" => Shape::Rbc,
        "ellipsoid" => {
            let a = c.axes.as_ref().ok_or_else(|| {
                at(
                    c.shape.span(),
                    format!("{} = \"ellipsoid\" needs axes", key("shape")),
                )
            })?;
            if !a.get_ref().iter().all(|v| v.is_finite() && *v > 0.0) {
                return Err(at(
                    a.span(),
                    format!("{} must be three positive numbers", key("axes")),
                ));
            }
            Shape::Ellipsoid { axes: *a.get_ref() }
        }
        s @ ("prolate" | "oblate") => {
            let v = c.reduced_volume.as_ref().ok_or_else(|| {
                at(
                    c.shape.span(),
                    format!("{} = \"{s}\" needs reduced_volume", key("shape")),
                )
            })?;
            let x = *v.get_ref();
            if !(x > 0.0 && x < 1.0) {
                return Err(at(
                    v.span(),
                    format!("{} must be in (0, 1), got {x}", key("reduced_volume")),
                ));
            }
            Shape::Spheroid {
                kind: if s == "prolate" {
                    Spheroid::Prolate
                } else {
                    Spheroid::Oblate
                },
                reduced_volume: x,
            }
        }
        other => {
            return Err(at(
                c.shape.span(),
                format!(
                    "{}: unknown shape \"{other}\" (sphere, ellipsoid, rbc, prolate, oblate)",
                    key("shape")
                ),
            ))
        }
    };
    // Keys of other shapes are refused, not ignored.
    if let (Some(v), false) = (&c.reduced_volume, matches!(shape, Shape::Spheroid { .. })) {
        return Err(at(
            v.span(),
            format!(
                "{} applies to shape = \"prolate\" or \"oblate\" only, not \"{}\"",
                key("reduced_volume"),
                c.shape.get_ref()
            ),
        ));
    }
    if let (Some(a), false) = (&c.axes, matches!(shape, Shape::Ellipsoid { .. })) {
        return Err(at(
            a.span(),
            format!(
                "{} applies to shape = \"ellipsoid\" only, not \"{}\"",
                key("axes"),
                c.shape.get_ref()
            ),
        ));
    }
    let get = |v: &Option<Spanned<f64>>, name: &str, default: f64, pos: bool| match v {
        Some(v) if pos => positive(v, &key(name)),
        Some(v) => finite(v, &key(name)),
        None => Ok(default),
    };
    let radius = get(&c.radius, "radius", 1.0, true)?;
    let inextensible = match &c.membrane {
        None => true,
        Some(m) => match m.get_ref().as_str() {
            "vesicle" => true,
            "capsule" => false,
            other => {
                return Err(at(
                    m.span(),
                    format!(
                        "{}: unknown membrane \"{other}\" (vesicle, capsule)",
                        key("membrane")
                    ),
                ))
            }
        },
    };
    let elastic_law = match &c.elastic_law {
        None => ElasticLaw::Skalak,
        Some(m) => match m.get_ref().as_str() {
            "skalak" => ElasticLaw::Skalak,
            "neo_hookean" => ElasticLaw::NeoHookean,
            other => {
                return Err(at(
                    m.span(),
                    format!(
                        "{}: unknown elastic law \"{other}\" (skalak, neo_hookean)",
                        key("elastic_law")
                    ),
                ))
            }
        },
    };
    // A capsule may have no bending stiffness (the benchmarks have none).
    let bending = get(
        &c.bending_modulus,
        "bending_modulus",
        if inextensible { 0.05 } else { 0.0 },
        inextensible,
    )?;
    if bending < 0.0 {
        let sp = c.bending_modulus.as_ref().expect("set").span();
        return Err(at(
            sp,
            format!("{} must not be negative", key("bending_modulus")),
        ));
    }
    let shear = get(&c.shear_modulus, "shear_modulus", 0.0, false)?;
    if shear < 0.0 {
        let sp = c.shear_modulus.as_ref().expect("set").span();
        return Err(at(
            sp,
            format!("{} must not be negative", key("shear_modulus")),
        ));
    }
    if !inextensible && shear == 0.0 {
        let sp = c
            .shear_modulus
            .as_ref()
            .map_or(c.membrane.as_ref().expect("capsule").span(), |s| s.span());
        return Err(at(
            sp,
            format!(
                "{} = \"capsule\" needs {} > 0: a capsule resists deformation through its \
                 elastic law alone",
                key("membrane"),
                key("shear_modulus")
            ),
        ));
    }
    let skalak_c = get(&c.skalak_c, "skalak_c", 10.0, true)?;
    // Keys that would be silently ignored are refused.
    if let (Some(l), true) = (&c.elastic_law, shear == 0.0) {
        return Err(at(
            l.span(),
            format!(
                "{} needs {} > 0 (without it the membrane has no shear elasticity)",
                key("elastic_law"),
                key("shear_modulus")
            ),
        ));
    }
    if let (Some(k), ElasticLaw::NeoHookean) = (&c.skalak_c, elastic_law) {
        return Err(at(
            k.span(),
            format!(
                "{} applies to the Skalak law only, not to elastic_law = \"neo_hookean\"",
                key("skalak_c")
            ),
        ));
    }
    let prestress = match &c.prestress {
        None => 0.0,
        Some(a) => {
            let v = finite(a, &key("prestress"))?;
            if !(0.0..1.0).contains(&v) {
                return Err(at(
                    a.span(),
                    format!(
                        "{} must be in [0, 1) (the inflation ratio: the stress-free reference is \
                         the shape scaled by 1/(1 + prestress)), got {v}",
                        key("prestress")
                    ),
                ));
            }
            if shear == 0.0 && v != 0.0 {
                return Err(at(
                    a.span(),
                    format!(
                        "{} needs {} > 0 (without shear elasticity the membrane has no \
                         reference to be stretched from)",
                        key("prestress"),
                        key("shear_modulus")
                    ),
                ));
            }
            v
        }
    };
    let lambda = get(&c.viscosity_ratio, "viscosity_ratio", 1.0, true)?;
    let vec3 = |v: &Option<Spanned<[f64; 3]>>, name: &str| -> Result<[f64; 3], SceneError> {
        match v {
            Some(v) if v.get_ref().iter().all(|x| x.is_finite()) => Ok(*v.get_ref()),
            Some(v) => Err(at(v.span(), format!("{} must be finite", key(name)))),
            None => Ok([0.0; 3]),
        }
    };
    let center = vec3(&c.center, "center")?;
    let force = vec3(&c.force, "force")?;
    let rot = match &c.orientation {
        Some(o) => {
            let v = o.get_ref();
            rotation([v[0], v[1], v[2]], v[3]).ok_or_else(|| {
                at(
                    o.span(),
                    format!(
                        "{} must be [axis_x, axis_y, axis_z, degrees] with a non-zero axis",
                        key("orientation")
                    ),
                )
            })?
        }
        None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };
    // Bounding radius from the shape itself (order 12 is plenty for the extent).
    let unit =
        unit_shape(&shape, 12).map_err(|e| at(c.shape.span(), format!("{}: {e}", key("shape"))))?;
    let bounding = bounding_radius(&unit)
        .map_err(|e| at(c.shape.span(), format!("{}: {e}", key("shape"))))?
        * radius;
    let line = line_col(text, c.shape.span().start).0;
    let base = CellSpec {
        shape,
        radius,
        center,
        rotation: rot,
        bending_modulus: bending,
        shear_modulus: shear,
        skalak_c,
        prestress,
        elastic_law,
        inextensible,
        viscosity_ratio: lambda,
        force,
        bounding_radius: bounding,
        line,
    };
    let count = match &c.count {
        Some(n) if *n.get_ref() == 0 => {
            return Err(at(n.span(), format!("{} must be at least 1", key("count"))))
        }
        Some(n) => *n.get_ref(),
        None => 1,
    };
    let placement = c.placement.as_ref().map(|p| p.get_ref().as_str());
    if let (Some(r), false) = (&c.region, placement == Some("random")) {
        return Err(at(
            r.span(),
            format!(
                "{} applies to placement = \"random\" only (a lattice, and a single cell, are \
                 centred on center)",
                key("region")
            ),
        ));
    }
    for (v, name) in [
        (&c.volume_fraction, "volume_fraction"),
        (&c.min_gap, "min_gap"),
    ] {
        if let (Some(v), false) = (v, placement == Some("packed")) {
            return Err(at(
                v.span(),
                format!("{} applies to placement = \"packed\" only", key(name)),
            ));
        }
    }
    if count == 1 && placement.is_none() {
        return Ok(vec![base]);
    }
    if placement == Some("packed") {
        let span = c.placement.as_ref().expect("set").span();
        if let Some(s) = &c.spacing {
            return Err(at(
                s.span(),
                format!(
                    "{} does not apply to placement = \"packed\"",
                    key("spacing")
                ),
            ));
        }
        let phi = match &c.volume_fraction {
            None => {
                return Err(at(
                    span,
                    format!("{} = \"packed\" needs volume_fraction", key("placement")),
                ))
            }
            Some(v) if !(*v.get_ref() > 0.0 && *v.get_ref() <= 0.6) => {
                return Err(at(
                    v.span(),
                    format!(
                        "{} must be in (0, 0.6], got {}",
                        key("volume_fraction"),
                        v.get_ref()
                    ),
                ))
            }
            Some(v) => *v.get_ref(),
        };
        let min_gap = match &c.min_gap {
            Some(g) => positive(g, &key("min_gap"))?,
            None => 0.05 * radius,
        };
        let fail = |m: String| at(span.clone(), format!("{}: {m}", key("placement")));
        // In a container the fluid's volume fixes the count; in a recycled tube, the window's.
        let region = match window.and_then(|w| window_volume(walls, w)) {
            Some(v) => Some(v),
            None => fluid_volume(walls).map_err(fail)?,
        };
        let (count, phi) = match region {
            None => (count, phi),
            Some(_) if c.count.is_some() => {
                let n = c.count.as_ref().expect("checked");
                return Err(at(
                    n.span(),
                    format!(
                        "{}: in a scene with a container wall the cells are packed in its fluid, \
                         and volume_fraction fixes their number; leave count out",
                        key("count")
                    ),
                ));
            }
            Some(v) => cells_in_walls(&base, phi, v),
        };
        let req = PackingRequest {
            count,
            volume_fraction: phi,
            min_gap,
            seed: c.seed.unwrap_or(1),
            order,
        };
        let (cells, report) = pack(&base, &req, walls, window).map_err(fail)?;
        packings.push(PackingReport { entry: k, ..report });
        return Ok(cells);
    }
    let spacing = match &c.spacing {
        Some(s) => positive(s, &key("spacing"))?,
        None => 2.2 * bounding,
    };
    let centers: Vec<[f64; 3]> = match placement.unwrap_or("lattice") {
        "lattice" => {
            let side = (count as f64).cbrt().ceil() as usize;
            let off = (side as f64 - 1.0) / 2.0;
            (0..count)
                .map(|i| {
                    let (a, b, cc) = (i % side, (i / side) % side, i / (side * side));
                    [
                        center[0] + spacing * (a as f64 - off),
                        center[1] + spacing * (b as f64 - off),
                        center[2] + spacing * (cc as f64 - off),
                    ]
                })
                .collect()
        }
        "random" => {
            let r = c.region.as_ref().ok_or_else(|| {
                at(
                    c.placement.as_ref().expect("set").span(),
                    format!(
                        "{} = \"random\" needs region = [[x0, y0, z0], [x1, y1, z1]]",
                        key("placement")
                    ),
                )
            })?;
            let [lo, hi] = *r.get_ref();
            if !(0..3).all(|d| hi[d] - lo[d] > 2.0 * bounding) {
                return Err(at(
                    r.span(),
                    format!("{} is too small for one cell", key("region")),
                ));
            }
            let mut rng = StdRng::seed_from_u64(c.seed.unwrap_or(1));
            let mut out: Vec<[f64; 3]> = Vec::with_capacity(count);
            // Bounding spheres 5 % apart, from this entry's cells and from earlier entries'.
            let gap = 2.0 * bounding * 1.05;
            let clear_of_earlier = |x: [f64; 3]| {
                earlier
                    .iter()
                    .all(|e| dist(x, e.center) >= 1.05 * (bounding + e.bounding_radius))
            };
            let mut tries = 0usize;
            while out.len() < count {
                tries += 1;
                if tries > 1000 * count {
                    let volume: f64 = (0..3).map(|d| hi[d] - lo[d]).product();
                    let ball = |r: f64| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
                    let cell = ball(radius);
                    let inside = |e: &&CellSpec| {
                        (0..3).all(|d| e.center[d] >= lo[d] && e.center[d] <= hi[d])
                    };
                    let taken: f64 = earlier.iter().filter(inside).map(|e| ball(e.radius)).sum();
                    return Err(at(
                        r.span(),
                        format!(
                            "{}: could only place {} of {count} cells without overlap: they ask for a \
                             volume fraction of {:.1} % of the region{}; enlarge the region or lower \
                             the count",
                            key("region"),
                            out.len(),
                            100.0 * count as f64 * cell / volume,
                            if taken > 0.0 {
                                format!(
                                    ", where earlier [[cells]] entries already take {:.1} %",
                                    100.0 * taken / volume
                                )
                            } else {
                                String::new()
                            }
                        ),
                    ));
                }
                let x: [f64; 3] =
                    std::array::from_fn(|d| rng.random_range(lo[d] + bounding..hi[d] - bounding));
                if out.iter().all(|y| dist(x, *y) >= gap) && clear_of_earlier(x) {
                    out.push(x);
                }
            }
            out
        }
        other => {
            return Err(at(
                c.placement.as_ref().expect("set").span(),
                format!(
                    "{}: unknown placement \"{other}\" (lattice, random, packed)",
                    key("placement")
                ),
            ))
        }
    };
    Ok(centers
        .into_iter()
        .map(|x| CellSpec {
            center: x,
            ..base.clone()
        })
        .collect())
}

pub(super) fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Largest distance of a grid point of the unit-size shape from its centroid.
pub(super) fn bounding_radius(s: &Surface) -> Result<f64, crate::vesicle::VesicleError> {
    let mut s = s.clone();
    s.scale_to_equivalent_radius(1.0)?;
    s.place_centroid([0.0; 3])?;
    let sht = crate::sph_harmonics::ShTransform::new(s.order())
        .map_err(crate::vesicle::VesicleError::Sph)?;
    let g = s.grid_positions(&sht)?;
    let n = g.len() / 3;
    Ok((0..n)
        .map(|j| (g[j].powi(2) + g[n + j].powi(2) + g[2 * n + j].powi(2)).sqrt())
        .fold(0.0, f64::max))
}

/// Cells whose surfaces intersect are an error naming both. Bounding spheres that do not
/// intersect clear a pair; the others are measured by the true surface distance (Newton's
/// closest points from the samples of each surface at order `2p` to the other surface, and
/// the closest pair of the two surfaces, [`SurfaceDistance::gaps_to`]), at the scene's order `p`.
pub(super) fn check_overlaps(
    cells: &[CellSpec],
    file: &Path,
    entry: &dyn Fn(usize) -> String,
    p: usize,
) -> Result<(), SceneError> {
    let err = |i: usize, message: String| SceneError {
        file: file.to_path_buf(),
        place: Some((cells[i].line, 1)),
        message,
    };
    let mut pairs = Vec::new();
    for i in 0..cells.len() {
        for j in 0..i {
            let d = dist(cells[i].center, cells[j].center);
            if d < cells[i].bounding_radius + cells[j].bounding_radius {
                pairs.push((j, i, d));
            }
        }
    }
    if pairs.is_empty() {
        return Ok(());
    }
    let sht = crate::sph_harmonics::ShTransform::new(2 * p).map_err(|e| err(0, e.to_string()))?;
    let mut surfaces: Vec<Option<SurfaceDistance>> = vec![None; cells.len()];
    for &(j, i, _) in &pairs {
        for k in [j, i] {
            if surfaces[k].is_none() {
                let cell = |e: crate::vesicle::VesicleError| {
                    err(k, format!("cell {k} of {}: {e}", entry(cells[k].line)))
                };
                let s = cells[k].surface(p).map_err(cell)?;
                surfaces[k] = Some(SurfaceDistance::new(p, s.coefs(), &sht).map_err(cell)?);
            }
        }
    }
    let mut scratch = DistanceScratch::new(p);
    for (j, i, d) in pairs {
        let (a, b) = (
            surfaces[j].as_ref().expect("built"),
            surfaces[i].as_ref().expect("built"),
        );
        let gap = a
            .gaps_to(b, &mut scratch, f64::INFINITY)
            .into_iter()
            .chain(b.gaps_to(a, &mut scratch, f64::INFINITY))
            .map(|(_, c)| c.distance)
            .fold(f64::INFINITY, f64::min);
        if gap <= 0.0 {
            return Err(err(
                i,
                format!(
                    "cells {j} (of {}) and {i} (of {}) overlap: their surfaces intersect (the \
                     deepest point of one is {:.4} inside the other; centres {d:.4} apart)",
                    entry(cells[j].line),
                    entry(cells[i].line),
                    -gap
                ),
            ));
        }
    }
    Ok(())
}
