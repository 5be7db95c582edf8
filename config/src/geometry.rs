//! Physical bounds of a robot description: what a configuration must satisfy before anything
//! (the simulator, the calibration, the loop) is built on it.

/// Most cables taut drives: the real-time loop's fixed arrays ([`taut_model::MAX_CABLES`], the one
/// home of the number).
pub use taut_model::MAX_CABLES;

/// Platform mass bounds, kg: from a 10 g sensor to a 5 t load. Outside these, tensions of a few
/// newtons (or kilonewtons) make no sense for the drives and load cells taut talks to.
pub const MASS_KG: (f64, f64) = (0.01, 5000.0);

/// Anchors and platform points lie within this of the tracker origin, m.
pub const MAX_COORD_M: f64 = 1000.0;

/// Two anchors closer than this are one anchor, m.
pub const MIN_ANCHOR_SEPARATION_M: f64 = 0.05;

/// The anchors must span at least this, m: a smaller frame has no workspace for a platform.
pub const MIN_FRAME_SPAN_M: f64 = 0.3;

/// Checks the geometry of nominal anchors and platform points. Errors are
/// `(cable index, key, message)`.
pub fn check(anchors: &[Option<[f64; 3]>], points: &[[f64; 3]]) -> Result<(), (usize, &'static str, String)> {
    let dist = |a: &[f64; 3], b: &[f64; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    for (j, p) in points.iter().enumerate() {
        if p.iter().any(|v| v.abs() > MAX_COORD_M) {
            return Err((j, "platform_point", format!("{p:?} is more than {MAX_COORD_M} m from the platform origin")));
        }
    }
    for (j, a) in anchors.iter().enumerate() {
        if let Some(a) = a {
            if a.iter().any(|v| v.abs() > MAX_COORD_M) {
                return Err((j, "anchor", format!("{a:?} is more than {MAX_COORD_M} m from the tracker origin; anchors are in m")));
            }
        }
    }
    let given: Vec<(usize, [f64; 3])> = anchors.iter().enumerate().filter_map(|(j, a)| a.map(|a| (j, a))).collect();
    for (k, (i, a)) in given.iter().enumerate() {
        for (j, b) in &given[k + 1..] {
            let d = dist(a, b);
            if d < MIN_ANCHOR_SEPARATION_M {
                return Err((
                    *j,
                    "anchor",
                    format!(
                        "{b:?} is {:.1} mm from the anchor of cable[{i}]; two cables need two anchors at least {} mm apart",
                        d * 1e3,
                        MIN_ANCHOR_SEPARATION_M * 1e3
                    ),
                ));
            }
        }
    }
    if given.len() < anchors.len() || given.len() < 3 {
        // The calibration does not need anchors; the checks of a frame need all of them.
        return Ok(());
    }
    let span = given.iter().flat_map(|(_, a)| given.iter().map(move |(_, b)| dist(a, b))).fold(0.0, f64::max);
    if span < MIN_FRAME_SPAN_M {
        return Err((
            0,
            "anchor",
            format!(
                "the anchors span only {:.0} mm; a frame needs at least {} m between its farthest anchors",
                span * 1e3,
                MIN_FRAME_SPAN_M
            ),
        ));
    }
    // Collinear anchors (all on one line) leave the platform free to swing about that line.
    let mut area = 0.0f64;
    for (x, (_, a)) in given.iter().enumerate() {
        for (y, (_, b)) in given.iter().enumerate().skip(x + 1) {
            for (_, c) in given.iter().skip(y + 1) {
                let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
                let cr = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                area = area.max(0.5 * (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt());
            }
        }
    }
    if area < 1e-3 * span * span {
        return Err((0, "anchor", "the anchors lie on one line; a cable robot needs anchors that span a plane or a volume".into()));
    }
    let pspan = points.iter().flat_map(|a| points.iter().map(move |b| dist(a, b))).fold(0.0, f64::max);
    if pspan >= span {
        // Blame the point farthest from the platform origin: the likely typo.
        let far = points.iter().enumerate().max_by(|a, b| dist(a.1, &[0.0; 3]).total_cmp(&dist(b.1, &[0.0; 3]))).map_or(0, |(j, _)| j);
        return Err((
            far,
            "platform_point",
            format!(
                "the platform points span {pspan:.3} m, no less than the frame's {span:.3} m: the platform cannot fit inside its frame"
            ),
        ));
    }
    Ok(())
}
