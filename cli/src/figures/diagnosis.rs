//! The figures of a diagnosis, one question each.

use super::calibration::{anchor_moves, thin};
use super::{colors, Figure, HLine, Marker, Panel, Style};
use taut_calib::diagnose::Diagnosis;

fn mm_points(x: &[f64], r: &[f64]) -> Vec<(f64, f64)> {
    x.iter().zip(r).map(|(a, b)| (*a, b * 1e3)).collect()
}

/// A panel of residuals before (hollow, light) and after (filled, dark, on top) a correction.
fn before_after(title: String, x_label: String, before: (Vec<(f64, f64)>, &str), after: Vec<(f64, f64)>, after_label: &str) -> Panel {
    let (b, lb) = thin(before.0, before.1);
    let (a, la) = thin(after, after_label);
    let mut p = Panel::new(title, x_label, "residual, mm").series(lb, b, colors::SKY, Style::Points(Marker::Circle)).series(
        la,
        a,
        colors::BLACK,
        Style::Points(Marker::Dot),
    );
    p.hlines.push(HLine { label: String::new(), y: 0.0, color: colors::GREY });
    p
}

/// All figures of a diagnosis, in the order they are written.
pub fn figures(d: &Diagnosis) -> Vec<Figure> {
    let mut figs = Vec::new();
    let panels = (0..d.cables)
        .map(|j| {
            let (tb, rb) = &d.baseline_residuals[j];
            let (ta, ra) = &d.final_residuals[j];
            before_after(
                format!("{}: residual (reading - model) against time", taut_config::cable_name(j)),
                "time, s".into(),
                (mm_points(tb, rb), "ideal model"),
                mm_points(ta, ra),
                "with the named effects",
            )
        })
        .collect();
    figs.push(Figure {
        stem: "diagnose-residual-vs-time".into(),
        question: "What is left of the mismatch once the named effects are modelled?".into(),
        caption: "Residual per cable against time, mm: hollow circles with the ideal model, dots with every named effect. \
                  Structure left in the dots (drifts, steps, episodes) is physics or a data problem no candidate explains."
            .into(),
        panels,
    });
    for f in &d.effects {
        let Some(p) = &f.plot else { continue };
        let x_label = format!("{}, {}", p.regressor.name(), p.regressor.unit());
        let panels = p
            .cables
            .iter()
            .enumerate()
            .map(|(j, (x, b, a))| {
                before_after(
                    format!("{}: residual against {}", taut_config::cable_name(j), p.regressor.name()),
                    x_label.clone(),
                    (mm_points(x, b), "before"),
                    mm_points(x, a),
                    &format!("with {}", f.effect.name()),
                )
            })
            .collect();
        figs.push(Figure {
            stem: format!("diagnose-{}", f.effect.name()),
            question: format!("What does the residual follow before and after modelling {}?", f.effect.name()),
            caption: format!(
                "Residual per cable against {} ({}), mm: hollow circles before the effect is modelled, dots after. A trend in the \
                 circles that the dots no longer show is what the effect explains.",
                p.regressor.name(),
                p.regressor.unit()
            ),
            panels,
        });
    }
    if d.baseline.params.anchors.len() == d.final_fit.params.anchors.len() && !d.final_fit.params.anchors.is_empty() {
        figs.push(anchor_moves(
            "diagnose-anchors",
            "from the ideal model to the model with the named effects",
            &d.baseline.params.anchors,
            &d.final_fit.params.anchors,
            &d.final_fit.sigma.anchors,
        ));
    }
    figs
}
