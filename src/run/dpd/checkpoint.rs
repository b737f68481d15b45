//! A DPD run's checkpoint: the whole run state written every `save_every` steps and read back
//! by `mobo dpd --resume`, so that a resumed run continues bit for bit.

use super::*;

/// The checkpoint of the whole run state.
pub(super) fn checkpoint(
    model: &Model,
    sampler: &ProfileSampler,
    rows: &[f64],
    wall: f64,
    p0: [f64; 3],
    placed: &str,
) -> Checkpoint {
    let sys = model.fluid();
    let n = sys.len();
    let mut c = Checkpoint::new(json!({
        "kind": "dpd",
        "step": sys.step,
        "particles": n,
        "bins": sampler.bins,
        "fluid_step": placed,
    }));
    let p = &sys.particles;
    for (name, v) in [
        ("x", &p.x),
        ("y", &p.y),
        ("z", &p.z),
        ("vx", &p.vx),
        ("vy", &p.vy),
        ("vz", &p.vz),
        ("fx", &sys.fx),
        ("fy", &sys.fy),
        ("fz", &sys.fz),
    ] {
        c.push(name, vec![n], v.clone());
    }
    c.push("id", vec![n], p.id.iter().map(|&i| i as f64).collect());
    c.push("moves", vec![n], p.moves.clone());
    c.push(
        "walls",
        vec![2],
        vec![sys.bounces as f64, sys.leaked as f64],
    );
    c.push("step", vec![], vec![sys.step as f64]);
    c.push("wall_s", vec![], vec![wall]);
    c.push("momentum0", vec![3], p0.to_vec());
    c.push(
        "observables",
        vec![rows.len() / OBS_COLS, OBS_COLS],
        rows.to_vec(),
    );
    let (state, shape) = sampler.state();
    c.push("profile_sampler", shape, state);
    if let Some(sim) = model.cells() {
        let st = sim.state();
        let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<f64>>();
        for (k, cs) in st.cells.iter().enumerate() {
            let nv = cs.x.len();
            c.push(format!("cell{k}_x"), vec![nv, 3], flat(&cs.x));
            c.push(format!("cell{k}_v"), vec![nv, 3], flat(&cs.v));
            c.push(format!("cell{k}_f"), vec![nv, 3], flat(&cs.f));
            c.push(format!("cell{k}_external"), vec![3], cs.external.to_vec());
        }
        c.push(
            "owner",
            vec![st.owner.len()],
            st.owner.iter().map(|&o| o as f64).collect(),
        );
        c.push(
            "membrane_counters",
            vec![3],
            st.counters.iter().map(|&v| v as f64).collect(),
        );
    }
    c
}

/// A restored run: the model, the sampler, the observables rows, the wall time so far, the
/// initial momentum, and where the earlier invocations stepped the fluid (`None`: not recorded).
pub(super) type Restored = (
    Model,
    ProfileSampler,
    Vec<f64>,
    f64,
    [f64; 3],
    Option<String>,
);

pub(super) fn restore(scene: &DpdScene, path: &Path) -> Result<Restored, DpdRunError> {
    let c = Checkpoint::read(path)?;
    let file = path.display().to_string();
    let bad = |why: String| DpdRunError::Checkpoint {
        file: file.clone(),
        why,
    };
    if c.meta.get("kind").and_then(|k| k.as_str()) != Some("dpd") {
        return Err(bad("not a DPD checkpoint".into()));
    }
    let get = |name: &str| {
        c.get(name)
            .map(|a| a.data.clone())
            .ok_or_else(|| bad(format!("array '{name}' missing")))
    };
    let ids = get("id")?;
    if ids
        .iter()
        .any(|&v| !(v >= 0.0 && v < u32::MAX as f64 && v.fract() == 0.0))
    {
        return Err(bad("particle ids are not integers below 2³²".into()));
    }
    let particles = Particles {
        x: get("x")?,
        y: get("y")?,
        z: get("z")?,
        vx: get("vx")?,
        vy: get("vy")?,
        vz: get("vz")?,
        id: ids.iter().map(|&v| v as u32).collect(),
        moves: get("moves")?,
    };
    let step = get("step")?.first().copied().unwrap_or(f64::NAN);
    if !(step >= 0.0 && step.fract() == 0.0) {
        return Err(bad(format!("step {step} is not a count")));
    }
    let forces = [get("fx")?, get("fy")?, get("fz")?];
    let mut sys = DpdSystem::restore(
        scene.params,
        scene.body,
        particles,
        scene.wall,
        forces,
        step as u64,
    )
    .map_err(|e| bad(format!("does not fit the scene: {e}")))?;
    let counts = get("walls")?;
    if counts.len() != 2 {
        return Err(bad("array 'walls' has the wrong shape".into()));
    }
    (sys.bounces, sys.leaked) = (counts[0] as u64, counts[1] as u64);
    // The frozen particles' velocities are in the checkpoint; the bounce-back needs the speed.
    sys.wall_speed = scene.wall_speed;
    let sampler_state = c
        .get("profile_sampler")
        .ok_or_else(|| bad("array 'profile_sampler' missing".into()))?;
    let sampler = ProfileSampler::from_state(
        flow_geometry(scene),
        scene.params.box_len,
        &sampler_state.data,
        &sampler_state.shape,
    )
    .ok_or_else(|| bad("profile sampler state does not parse".into()))?;
    let rows = get("observables")?;
    let wall = get("wall_s")?.first().copied().unwrap_or(0.0);
    let p0 = get("momentum0")?;
    if p0.len() != 3 || rows.len() % OBS_COLS != 0 {
        return Err(bad("momentum0 or observables have the wrong shape".into()));
    }
    let model = if scene.cells.is_empty() {
        Model::Fluid(Box::new(sys))
    } else {
        let triples = |name: &str, n: usize| -> Result<Vec<[f64; 3]>, DpdRunError> {
            let v = get(name)?;
            if v.len() != 3 * n {
                return Err(bad(format!(
                    "array '{name}' has {} values, the scene's cell needs {}",
                    v.len(),
                    3 * n
                )));
            }
            Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        };
        let mut cells = Vec::with_capacity(scene.cells.len());
        for (k, sc) in scene.cells.iter().enumerate() {
            let nv = sc.spec.vertices.len();
            let ext = triples(&format!("cell{k}_external"), 1)?;
            cells.push(CellState {
                x: triples(&format!("cell{k}_x"), nv)?,
                v: triples(&format!("cell{k}_v"), nv)?,
                f: triples(&format!("cell{k}_f"), nv)?,
                external: ext[0],
            });
        }
        let owner = get("owner")?;
        if owner
            .iter()
            .any(|&o| !(o >= 0.0 && o <= u32::MAX as f64 && o.fract() == 0.0))
        {
            return Err(bad(
                "array 'owner' holds values that are not cell indices".into()
            ));
        }
        let counters = get("membrane_counters")?;
        if counters.len() != 3 {
            return Err(bad("array 'membrane_counters' has the wrong shape".into()));
        }
        let state = SuspensionState {
            cells,
            owner: owner.iter().map(|&o| o as u32).collect(),
            counters: [counters[0] as u64, counters[1] as u64, counters[2] as u64],
        };
        let specs = scene.cells.iter().map(|c| c.spec.clone()).collect();
        Model::Cells(
            Box::new(
                DpdSuspension::restore(sys, specs, scene.coupling, state)
                    .map_err(|e| bad(format!("does not fit the scene: {e}")))?,
            ),
            None,
        )
    };
    let earlier = c
        .meta
        .get("fluid_step")
        .and_then(|v| v.as_str())
        .map(str::to_string);
    Ok((model, sampler, rows, wall, [p0[0], p0[1], p0[2]], earlier))
}
