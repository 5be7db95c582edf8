//! Wall time of the parts of a calibration (gather, variances, one pass, the final pass) on a
//! recording, each repeated; run it alone (or under `chrt`) for stable figures.
use std::time::Instant;
use taut_calib::{noise, solver, CalibOptions, RobustLoss};
use taut_config::recording::Recording;

fn main() {
    let path = std::env::args().nth(1).expect("REC.csv");
    let (rec, _) = Recording::load(&path).unwrap();
    let b = vec![[0.0; 3]; rec.n_cables];
    let opts = CalibOptions::default();
    let w = noise::Weighting::of(&rec, &opts);
    let nm = noise::NoiseModel::new(&opts, w);
    let x0 = [3.512 + 0.08, -1.738 - 0.05, 3.987 + 0.06, 0.812 - 0.07];
    let reps = 50;
    let t = Instant::now();
    let mut data = Vec::new();
    for _ in 0..10 {
        data = noise::gather(&rec, &b, &opts, w);
    }
    let gather = t.elapsed().as_secs_f64() * 1e3 / 10.0;
    let t = Instant::now();
    for _ in 0..reps {
        data[0].set_variances(&x0, &nm);
    }
    let var = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let d = &data[0];
    let mut c = 0.0;
    let mut time = |loss| {
        let t = Instant::now();
        for _ in 0..reps {
            c += solver::pass(d, 0, d.len(), &x0, loss).cost;
        }
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    };
    let ls = time(RobustLoss::None);
    let hub = time(RobustLoss::Huber { k: 2.0 });
    let t = Instant::now();
    for _ in 0..reps {
        c += solver::final_pass(d, 0, d.len(), &x0, RobustLoss::Huber { k: 2.0 }, 6.0).pass.cost;
    }
    let fin = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
    println!(
        "gather {gather:.2} ms (4 cables), set_variances {var:.3} ms, pass LS {ls:.3} ms, pass Huber {hub:.3} ms, final pass {fin:.3} ms ({} readings) [{c:.0}]",
        d.len()
    );
}
