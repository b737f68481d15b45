//! The cells of a DPD scene: `[[dpd.cells]]` given as membranes, and the cell scene's
//! `[[cells]]` mapped into the fluid by `[dpd.from_cells]`, with the fluid–membrane coupling.

use super::*;

/// The cell scene's `[[cells]]` of this file (read as `mobo run` reads it, with its
/// placement and checks) mapped into the fluid by `[dpd.from_cells]`, each with the line of its
/// entry.
///
/// A vesicle or RBC (`membrane = "vesicle"`, locally inextensible) keeps Fedosov's nearly
/// incompressible area penalties; a capsule's area modulus `K = G_s (1 + 2C)` (Skalak) or
/// `3 G_s` (neo-Hookean) is the network's `2μ0 + k_a + k_d`, with `k_a = k_d`. A fluid membrane
/// (`shear_modulus = 0`) has no counterpart in the spring network and is refused, and so is a
/// viscosity ratio other than 1 unless `[dpd.coupling] inner_gamma` sets the inner fluid.
pub(super) fn mapped_cells(
    file: &Path,
    text: &str,
    fc: &FromCellsSection,
    params: &DpdParams,
    wall: Option<&Wall>,
    coupling: Option<&CouplingSection>,
) -> Result<(CellMapping, Vec<(usize, DpdCell)>), SceneError> {
    let section = |key: &str, why: String| {
        let mut e = SceneError::new(file, format!("[dpd.from_cells] {key}: {why}"));
        e.place = key_place_in(text, "[dpd.from_cells]", key)
            .or_else(|| section_place(text, "[dpd.from_cells]", 0));
        e
    };
    check_positive(&section, &[("length", fc.length), ("energy", fc.energy)])?;
    check_nonnegative(
        &section,
        &[
            ("ka", fc.ka),
            ("kd", fc.kd),
            ("kv", fc.kv),
            ("gamma_t", fc.gamma_t),
            ("gamma_c", fc.gamma_c),
        ],
    )?;
    check_subdivisions(&section, fc.subdivisions)?;
    let l = params.box_len;
    let origin = fc.origin.unwrap_or([0.5 * l[0], 0.5 * l[1], 0.5 * l[2]]);
    if origin.iter().any(|v| !v.is_finite()) {
        return Err(section("origin", format!("must be finite, got {origin:?}")));
    }
    let rot = match fc.rotate {
        None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        Some([x, y, z, deg]) => crate::scene::cells::rotation([x, y, z], deg).ok_or_else(|| {
            section(
                "rotate",
                format!(
                    "must be a non-zero axis and an angle in degrees, got {:?}",
                    [x, y, z, deg]
                ),
            )
        })?,
    };
    let turn = |v: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|i| rot[i][0] * v[0] + rot[i][1] * v[1] + rot[i][2] * v[2])
    };
    let scene = crate::scene::cells::parse(file, text)?;
    let first_wall = scene
        .walls
        .first()
        .map(|w| w.line)
        .or(scene.plane.map(|p| p.line));
    if let Some(line) = first_wall {
        let mut e = SceneError::new(
            file,
            "[[walls]] are the boundary-integral solver's walls, which [dpd.from_cells] does \
             not map: a DPD fluid has its own walls ([dpd] walls = { kind = \"planes\" | \
             \"cylinder\" })",
        );
        e.place = (line > 0).then_some((line, 1));
        return Err(e);
    }
    let (s, e) = (fc.length, fc.energy);
    let inner_gamma = coupling.and_then(|c| c.inner_gamma).is_some();
    let mut out = Vec::with_capacity(scene.cells.len());
    for spec in &scene.cells {
        let line = spec.line;
        let located = |key: &str, why: String| SceneError {
            file: file.to_path_buf(),
            place: Some((line, 1)),
            message: format!(
                "[[cells]] entry at line {line}, mapped by [dpd.from_cells]: {key}: {why}"
            ),
        };
        if spec.shear_modulus <= 0.0 {
            return Err(located(
                "shear_modulus",
                "0 is a fluid membrane, which the DPD spring network cannot model (it needs \
                 a shear modulus μ0 > 0): give the cell a shear_modulus"
                    .into(),
            ));
        }
        if spec.prestress != 0.0 {
            return Err(located(
                "prestress",
                format!(
                    "{}: the DPD spring network is built stress-free at the cell's shape and \
                     cannot start prestressed; leave prestress out of a cell mapped to DPD",
                    spec.prestress
                ),
            ));
        }
        if spec.viscosity_ratio != 1.0 && !inner_gamma {
            return Err(located(
                "viscosity_ratio",
                format!(
                    "{} is not mapped by itself: set [dpd.coupling] inner_gamma for the inner \
                     fluid of the DPD cells (docs/dpd_inner_viscosity.md gives the ratio it makes)",
                    spec.viscosity_ratio
                ),
            ));
        }
        let mu0 = spec.shear_modulus * e / (s * s);
        let (ka, kd) = if spec.inextensible {
            (fc.ka, fc.kd)
        } else {
            let k_area = match spec.elastic_law {
                ElasticLaw::Skalak => spec.shear_modulus * (1.0 + 2.0 * spec.skalak_c),
                ElasticLaw::NeoHookean => 3.0 * spec.shear_modulus,
            } * e
                / (s * s);
            if k_area < 2.0 * mu0 && (fc.ka.is_none() || fc.kd.is_none()) {
                return Err(located(
                    "skalak_c",
                    format!(
                        "{}: the capsule's area modulus G_s (1 + 2C) is below the spring \
                         network's own 2μ0 (C < 1/2); give [dpd.from_cells] ka and kd",
                        spec.skalak_c
                    ),
                ));
            }
            let half = 0.5 * (k_area - 2.0 * mu0);
            (Some(fc.ka.unwrap_or(half)), Some(fc.kd.unwrap_or(half)))
        };
        let membrane = MembraneInputs {
            shear_modulus: mu0,
            bending_rigidity: spec.bending_modulus * e,
            bending: BendingModel::Juelicher { c0: 0.0 },
            ka,
            kd,
            kv: fc.kv,
            gamma_t: fc.gamma_t,
            gamma_c: fc.gamma_c,
        };
        let shape_err = |err: crate::vesicle::VesicleError| located("shape", err.to_string());
        let at_origin = SceneCell {
            center: [0.0; 3],
            rotation: mat_mul(rot, spec.rotation),
            ..spec.clone()
        };
        let mut surface = at_origin.surface(16).map_err(shape_err)?;
        surface
            .scale_to_equivalent_radius(spec.radius * s)
            .map_err(shape_err)?;
        let placed = Placed {
            shape: shape_name(&spec.shape),
            radius: spec.radius * s,
            surface: &surface,
            center: {
                let c = turn(spec.center);
                [0, 1, 2].map(|k| origin[k] + s * c[k])
            },
            subdivisions: fc.subdivisions,
            force: turn(spec.force).map(|f| f * e / s),
        };
        out.push((
            line,
            build_cell(&located, &placed, &membrane, params, wall)?,
        ));
    }
    let mapping = CellMapping {
        length: s,
        energy: e,
        origin,
        rotation: rot,
        cells: out.len(),
    };
    Ok((mapping, out))
}

/// `a b` of 3 × 3 matrices.
fn mat_mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// The scene-file name of a cell scene's shape.
fn shape_name(shape: &Shape) -> &'static str {
    match shape {
        Shape::Sphere => "sphere",
        Shape::Ellipsoid { .. } => "ellipsoid",
        Shape::Rbc => "rbc",
        Shape::Spheroid {
            kind: shapes::Spheroid::Prolate,
            ..
        } => "prolate",
        Shape::Spheroid { .. } => "oblate",
    }
}

/// `[dpd.coupling]` with its defaults ([`CouplingParams::default`]).
pub(super) fn coupling_params(
    file: &Path,
    text: &str,
    c: Option<&CouplingSection>,
) -> Result<CouplingParams, SceneError> {
    let mut out = CouplingParams::default();
    let Some(c) = c else { return Ok(out) };
    out.gamma_out = c.gamma_out.unwrap_or(out.gamma_out);
    out.gamma_in = c.gamma_in.unwrap_or(out.gamma_in);
    out.power = c.power.unwrap_or(out.power);
    out.inner_extra_gamma = c.inner_gamma.unwrap_or(out.inner_extra_gamma);
    out.contact_a = c.contact_a.unwrap_or(out.contact_a);
    out.vertex_mass = c.vertex_mass.unwrap_or(out.vertex_mass);
    out.check_every = c.check_every.unwrap_or(out.check_every);
    out.validate().map_err(|e| {
        let mut err = SceneError::new(file, format!("[dpd.coupling]: {e}"));
        err.place = section_place(text, "[dpd.coupling]", 0);
        err
    })?;
    Ok(out)
}

/// The `k`-th `[[dpd.cells]]` entry built: its shape on the icosphere, the membrane from its
/// moduli, checked against the box and the walls.
pub(super) fn cell(
    file: &Path,
    text: &str,
    k: usize,
    c: &CellSection,
    params: &DpdParams,
    wall: Option<&Wall>,
) -> Result<DpdCell, SceneError> {
    let located = |key: &str, why: String| {
        let mut e = SceneError::new(file, format!("[[dpd.cells]] entry {}: {key}: {why}", k + 1));
        e.place = cell_key_place(text, k, key).or_else(|| section_place(text, "[[dpd.cells]]", k));
        e
    };
    check_positive(
        &located,
        &[("radius", c.radius), ("shear_modulus", c.shear_modulus)],
    )?;
    check_nonnegative(
        &located,
        &[
            ("bending_rigidity", Some(c.bending_rigidity)),
            ("ka", c.ka),
            ("kd", c.kd),
            ("kv", c.kv),
            ("gamma_t", c.gamma_t),
        ],
    )?;
    check_subdivisions(&located, c.subdivisions)?;
    let order = 16;
    let shape_err = |e: crate::vesicle::VesicleError| located("shape", e.to_string());
    let mut surface = match (c.shape.as_str(), c.reduced_volume) {
        ("sphere", None) => shapes::sphere(order, 1.0).map_err(shape_err)?,
        ("rbc", None) => shapes::rbc(order).map_err(shape_err)?,
        ("prolate" | "oblate", Some(v)) => {
            if !(v > 0.0 && v <= 1.0) {
                return Err(located(
                    "reduced_volume",
                    format!("must be in (0, 1], got {v}"),
                ));
            }
            let kind = if c.shape == "prolate" {
                shapes::Spheroid::Prolate
            } else {
                shapes::Spheroid::Oblate
            };
            shapes::reduced_volume_spheroid(order, v, kind, 1.0).map_err(shape_err)?
        }
        ("prolate" | "oblate", None) => {
            return Err(located(
                "reduced_volume",
                format!("shape \"{}\" needs reduced_volume", c.shape),
            ))
        }
        (_, Some(_)) if c.shape == "sphere" || c.shape == "rbc" => {
            return Err(located(
                "reduced_volume",
                format!("only prolate and oblate shapes take it, not \"{}\"", c.shape),
            ))
        }
        (other, _) => {
            return Err(located(
                "shape",
                format!(
                    "unknown shape \"{other}\" (expected \"sphere\", \"rbc\", \"prolate\" or \"oblate\")"
                ),
            ))
        }
    };
    surface
        .scale_to_equivalent_radius(c.radius)
        .map_err(shape_err)?;
    let bending = match (c.bending.as_str(), c.c0, c.theta0) {
        ("juelicher", c0, None) => BendingModel::Juelicher {
            c0: c0.unwrap_or(0.0),
        },
        ("kantor_nelson", None, theta0) => BendingModel::KantorNelson {
            theta0: theta0.unwrap_or(0.0),
        },
        ("juelicher", _, Some(_)) => {
            return Err(located(
                "theta0",
                "Jülicher bending takes c0, not theta0".into(),
            ))
        }
        ("kantor_nelson", Some(_), _) => {
            return Err(located(
                "c0",
                "Kantor–Nelson bending takes theta0, not c0".into(),
            ))
        }
        (other, _, _) => {
            return Err(located(
                "bending",
                format!("unknown model \"{other}\" (expected \"juelicher\" or \"kantor_nelson\")"),
            ))
        }
    };
    let membrane = MembraneInputs {
        shear_modulus: c.shear_modulus,
        bending_rigidity: c.bending_rigidity,
        bending,
        ka: c.ka,
        kd: c.kd,
        kv: c.kv,
        gamma_t: c.gamma_t,
        gamma_c: c.gamma_c,
    };
    let force = c.force.unwrap_or([0.0; 3]);
    let placed = Placed {
        shape: &c.shape,
        radius: c.radius,
        surface: &surface,
        center: c.center,
        subdivisions: c.subdivisions,
        force,
    };
    build_cell(&located, &placed, &membrane, params, wall)
}

/// The membrane of a cell before its mesh is known: the moduli and the values that override
/// Fedosov's defaults ([`Moduli::new`]).
struct MembraneInputs {
    shear_modulus: f64,
    bending_rigidity: f64,
    bending: BendingModel,
    ka: Option<f64>,
    kd: Option<f64>,
    kv: Option<f64>,
    gamma_t: Option<f64>,
    gamma_c: Option<f64>,
}

/// A cell's shape at its size (centroid at the origin) and where it goes.
struct Placed<'a> {
    shape: &'a str,
    radius: f64,
    surface: &'a Surface,
    center: [f64; 3],
    subdivisions: u32,
    force: [f64; 3],
}

/// A cell built from its placed shape and membrane: the icosphere mapped onto the surface,
/// the membrane's parameters from the moduli, checked against the box and the walls
/// (`located(key, why)` makes the error of a key of the cell's entry).
fn build_cell(
    located: &dyn Fn(&str, String) -> SceneError,
    c: &Placed<'_>,
    m: &MembraneInputs,
    params: &DpdParams,
    wall: Option<&Wall>,
) -> Result<DpdCell, SceneError> {
    let shape_err = |e: crate::vesicle::VesicleError| located("shape", e.to_string());
    let mesh = CellMesh::icosphere(c.surface, c.subdivisions).map_err(shape_err)?;
    let lengths = mesh.edge_lengths();
    let l0 = lengths.iter().sum::<f64>() / lengths.len() as f64;
    // Fedosov's values (`Moduli::new`) where the entry gives none.
    let base = Moduli::new(m.shear_modulus, m.bending_rigidity, m.bending, l0);
    let membrane = MembraneParams::from_moduli(&Moduli {
        ka: m.ka.unwrap_or(base.ka),
        kd: m.kd.unwrap_or(base.kd),
        kv: m.kv.unwrap_or(base.kv),
        kbt: params.pair.kbt.max(f64::MIN_POSITIVE),
        gamma_t: m.gamma_t.unwrap_or(base.gamma_t),
        gamma_c: m.gamma_c,
        ..base
    })
    .map_err(|e| located("membrane moduli", e.to_string()))?;
    let l = params.box_len;
    for a in 0..3 {
        if !(c.center[a].is_finite() && c.center[a] >= 0.0 && c.center[a] < l[a]) {
            return Err(located(
                "center",
                format!(
                    "{:?} is not inside the box {:?} (component {} out of [0, {}))",
                    c.center,
                    l,
                    ["x", "y", "z"][a],
                    l[a]
                ),
            ));
        }
    }
    let vertices: Vec<[f64; 3]> = mesh
        .vertices
        .iter()
        .map(|v| [0, 1, 2].map(|a| v[a] + c.center[a]))
        .collect();
    for a in 0..3 {
        let (lo, hi) = vertices
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v[a]), hi.max(v[a]))
            });
        if hi - lo + 2.0 * params.pair.rc > l[a] {
            return Err(located(
                "radius",
                format!(
                    "the cell spans {:.3} along {}: with 2 r_c it must fit in the box ({})",
                    hi - lo,
                    ["x", "y", "z"][a],
                    l[a]
                ),
            ));
        }
    }
    if let Some(w) = wall {
        if let Some(v) = vertices
            .iter()
            .position(|&x| w.sdf(x) > -0.5 * params.pair.rc)
        {
            return Err(located(
                "center",
                format!(
                    "the cell reaches into the wall (vertex {v} at {:?} is closer than r_c/2 to it)",
                    vertices[v]
                ),
            ));
        }
    }
    let force = c.force;
    if force.iter().any(|f| !f.is_finite()) {
        return Err(located("force", format!("must be finite, got {force:?}")));
    }
    Ok(DpdCell {
        shape: c.shape.to_string(),
        radius: c.radius,
        spec: CellSpec {
            vertices,
            triangles: mesh.triangles.clone(),
            params: membrane,
        },
        force,
    })
}
