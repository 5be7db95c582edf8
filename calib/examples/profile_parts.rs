//! CPU time of the parts of a calibration (gather, variances, one pass, metrics) on a recording.
use taut_calib::{metrics, noise, solver, CalibOptions, RobustLoss};
use taut_config::recording::Recording;

fn cpu_ms() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse::<f64>().ok()))
        .unwrap_or(f64::NAN)
        * 1e-6
}

fn main() {
    let path = std::env::args().nth(1).expect("REC.csv");
    let (rec, _) = Recording::load(&path).unwrap();
    let b = vec![[0.0; 3]; rec.n_cables];
    let opts = CalibOptions::default();
    let w = noise::Weighting::of(&rec, &opts);
    let nm = noise::NoiseModel::new(&opts, w);
    let x0 = [3.512 + 0.08, -1.738 - 0.05, 3.987 + 0.06, 0.812 - 0.07];
    for _ in 0..3 {
        let c0 = cpu_ms();
        let mut data = noise::gather(&rec, &b, &opts, w);
        let c1 = cpu_ms();
        data[0].set_variances(&x0, &nm);
        let c2 = cpu_ms();
        let d = &data[0];
        let mut c = 0.0;
        for _ in 0..20 {
            c += solver::pass(d, 0, d.len(), &x0, RobustLoss::Huber { k: 2.0 }).cost;
        }
        let c3 = cpu_ms();
        let p = taut_calib::Params { anchors: vec![[3.5, -1.7, 4.0]; 4], l0: vec![0.0; 4] };
        let rp = metrics::rms_peak_present(&rec, &b, &p);
        let c4 = cpu_ms();
        println!(
            "cpu: gather {:.2} ms, set_variances {:.2} ms, pass {:.3} ms ({} readings), rms_peak_present {:.2} ms [{c:.0} {}]",
            c1 - c0, c2 - c1, (c3 - c2) / 20.0, d.len(), c4 - c3, rp.n
        );
    }
}
