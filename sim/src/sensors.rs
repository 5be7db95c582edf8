//! Sensor models: the position tracker, the drum encoders and the load cells.
//!
//! | sensor    | default noise                                                              |
//! |-----------|----------------------------------------------------------------------------|
//! | tracker   | 1.5 mm 1-sigma per axis, white; 0.2 % outliers of ~5 cm; 0.5 % missing (NaN) in bursts |
//! | encoder   | 0.05 mm 1-sigma, then quantised to 0.01 mm                                 |
//! | load cell | 0.3 N 1-sigma plus a per-cell offset (0.5 N 1-sigma)                       |

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal};

/// Sensor noise. [`Noise::default`] is a realistic set, [`Noise::none`] exact sensors.
#[derive(Debug, Clone, PartialEq)]
pub struct Noise {
    /// Tracker noise, 1-sigma per axis, m (the marginal sigma, whatever [`Noise::tracker_phi`]).
    pub tracker_sigma_m: f64,
    /// Lag-1 correlation of the tracker noise from one sample to the next, per axis, in
    /// `[0, 1)`: AR(1) noise `e_i = phi e_(i-1) + sqrt(1 - phi^2) sigma g_i` with the stationary
    /// marginal `sigma` ([`Noise::tracker_sigma_m`]), started stationary. 0 (the default) is white
    /// noise.
    pub tracker_phi: f64,
    /// Probability that a tracker sample is an outlier.
    pub tracker_outlier_prob: f64,
    /// Typical size of a tracker outlier, m.
    pub tracker_outlier_m: f64,
    /// Fraction of tracker samples missing (NaN).
    pub tracker_dropout_prob: f64,
    /// Mean number of consecutive missing tracker samples.
    pub tracker_dropout_len: usize,
    /// Encoder quantum, m (0: not quantised).
    pub encoder_quantum_m: f64,
    /// Encoder noise, 1-sigma, m: white, drawn anew for every reading.
    pub encoder_sigma_m: f64,
    /// Winding irregularity, RMS, m: how far the cable paid out departs from what the drum's
    /// angle says, as a fixed function of the angle ([`Winding`]). Unlike the white noise it is
    /// the same every time the drum passes an angle, and the drive's position loop, which works
    /// on the angle, does not see it: a reading commanded back holds the drum where it was.
    /// 0 (the default): none.
    pub encoder_winding_m: f64,
    /// Correlation length of the winding irregularity along the cable, m.
    pub encoder_winding_wavelength_m: f64,
    /// Load-cell noise, 1-sigma, N.
    pub loadcell_sigma_n: f64,
    /// Load-cell offset, 1-sigma of the per-cell constant, N.
    pub loadcell_offset_n: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Noise {
            tracker_sigma_m: 1.5e-3,
            tracker_phi: 0.0,
            tracker_outlier_prob: 0.002,
            tracker_outlier_m: 0.05,
            tracker_dropout_prob: 0.005,
            tracker_dropout_len: 4,
            encoder_quantum_m: 1e-5,
            encoder_sigma_m: 5e-5,
            encoder_winding_m: 0.0,
            encoder_winding_wavelength_m: 5e-4,
            loadcell_sigma_n: 0.3,
            loadcell_offset_n: 0.5,
        }
    }
}

impl Noise {
    /// Exact sensors: no noise, outliers, dropouts, quantisation or offsets.
    pub fn none() -> Self {
        Noise {
            tracker_sigma_m: 0.0,
            tracker_phi: 0.0,
            tracker_outlier_prob: 0.0,
            tracker_outlier_m: 0.0,
            tracker_dropout_prob: 0.0,
            tracker_dropout_len: 1,
            encoder_quantum_m: 0.0,
            encoder_sigma_m: 0.0,
            encoder_winding_m: 0.0,
            encoder_winding_wavelength_m: 5e-4,
            loadcell_sigma_n: 0.0,
            loadcell_offset_n: 0.0,
        }
    }
}

fn gauss(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    if sigma > 0.0 {
        let z: f64 = StandardNormal.sample(rng);
        sigma * z
    } else {
        0.0
    }
}

/// The position tracker: noise (white or AR(1)), rare outliers, bursts of missing samples.
#[derive(Debug, Clone)]
pub struct Tracker {
    noise: Noise,
    missing_left: usize,
    /// The AR(1) noise state per axis in units of sigma (`None` before the first sample).
    ar: Option<[f64; 3]>,
}

impl Tracker {
    /// A tracker with `noise`.
    ///
    /// # Panics
    /// If `noise.tracker_phi` is not in `[0, 1)`.
    pub fn new(noise: &Noise) -> Self {
        assert!((0.0..1.0).contains(&noise.tracker_phi), "tracker_phi {} not in [0, 1)", noise.tracker_phi);
        Tracker { noise: noise.clone(), missing_left: 0, ar: None }
    }

    /// One measurement of the true position `p` (NaN while a dropout lasts).
    pub fn measure(&mut self, p: [f64; 3], rng: &mut ChaCha8Rng) -> [f64; 3] {
        let n = &self.noise;
        // Draw the same number of variates every sample so that switching one effect does not
        // shift the random stream of the others.
        let u_drop: f64 = rng.gen();
        let len_draw: f64 = rng.gen();
        let u_out: f64 = rng.gen();
        let mut g: [f64; 3] = std::array::from_fn(|_| gauss(rng, 1.0));
        let o: [f64; 3] = std::array::from_fn(|_| gauss(rng, 1.0));
        if n.tracker_phi > 0.0 {
            // AR(1): the state moves on every sample, dropouts too (the noise is the tracker's,
            // not the reading's); the first sample draws from the stationary marginal.
            let (phi, innov) = (n.tracker_phi, (1.0 - n.tracker_phi * n.tracker_phi).sqrt());
            let e = match self.ar {
                None => g,
                Some(e) => std::array::from_fn(|k| phi * e[k] + innov * g[k]),
            };
            self.ar = Some(e);
            g = e;
        }
        if self.missing_left == 0 && n.tracker_dropout_prob > 0.0 {
            let mean = n.tracker_dropout_len.max(1) as f64;
            if u_drop < n.tracker_dropout_prob / mean {
                // Burst length uniform in 1..=2*mean-1 (mean `mean`).
                self.missing_left = 1 + (len_draw * (2.0 * mean - 1.0)).floor() as usize;
            }
        }
        if self.missing_left > 0 {
            self.missing_left -= 1;
            return [f64::NAN; 3];
        }
        let mut m: [f64; 3] = std::array::from_fn(|k| p[k] + n.tracker_sigma_m * g[k]);
        if u_out < n.tracker_outlier_prob {
            // ~5 cm in a random direction, magnitude spread +-20 %.
            let r = (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt().max(1e-9);
            let mag = n.tracker_outlier_m * (1.0 + 0.2 * (len_draw - 0.5));
            for k in 0..3 {
                m[k] += mag * o[k] / r;
            }
        }
        m
    }
}

/// Play operator: the output follows the input only once the input has moved by more than half
/// the play width away from it (backlash in the drive train).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Backlash {
    width: f64,
    y: Option<f64>,
}

impl Backlash {
    /// A play of `width` m (0: the output is the input).
    pub fn new(width: f64) -> Self {
        Backlash { width, y: None }
    }

    /// The output for input `x`.
    pub fn update(&mut self, x: f64) -> f64 {
        let h = 0.5 * self.width;
        let y = match self.y {
            None => x,
            Some(y) => y.clamp(x - h, x + h),
        };
        self.y = Some(y);
        y
    }
}

/// A drum whose effective radius changes as the cable winds in layers: `r(phi) = r0 + g phi`
/// at the angle `phi` turned from the cable length zero (`g` the radius change per radian paid
/// out). Its encoder converts the angle at the radius `r0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drum {
    /// Radius at the cable length zero, m.
    pub r0: f64,
    /// Radius change per radian paid out, m.
    pub g: f64,
}

impl Drum {
    /// A drum of radius `r0` (m) at the cable length zero changing by `per_turn` (m) each turn
    /// paid out.
    pub fn new(r0: f64, per_turn: f64) -> Drum {
        Drum { r0, g: per_turn / std::f64::consts::TAU }
    }

    /// The length the encoder derives (`r0 phi`) for the paid-out length `length`: the angle
    /// solves `length = r0 phi + g phi^2 / 2` (the arc of a radius growing linearly with the
    /// angle), the root through zero. Where the radius would reach zero the angle is where it does.
    pub fn encoder_length(&self, length: f64) -> f64 {
        let disc = (self.r0 * self.r0 + 2.0 * self.g * length).max(0.0);
        let phi = 2.0 * length / (self.r0 + disc.sqrt());
        self.r0 * phi
    }

    /// The paid-out length as a polynomial in the encoder's `u = r0 phi`: `u + q u^2` with this
    /// `q = g / (2 r0^2)`, 1/m (exact: the arc is quadratic in the angle).
    pub fn quadratic_per_m(&self) -> f64 {
        self.g / (2.0 * self.r0 * self.r0)
    }

    /// The paid-out length at which the encoder derives `enc` (the inverse of
    /// [`Drum::encoder_length`]).
    pub fn length(&self, enc: f64) -> f64 {
        let phi = enc / self.r0;
        self.r0 * phi + 0.5 * self.g * phi * phi
    }
}

/// An eccentric drum: its axis sits `amplitude_m` off the centre of a drum of radius `radius_m`,
/// so the length it pays out leads the encoder's `radius x angle` by
/// `amplitude (sin(angle + phase) - sin(phase))`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eccentric {
    /// Offset of the axis from the drum's centre, m.
    pub amplitude_m: f64,
    /// The drum's radius, m.
    pub radius_m: f64,
    /// The drum's angle at the paid-out length zero, rad.
    pub phase: f64,
}

impl Eccentric {
    /// How far the paid-out length `d` (m) leads the encoder's count, m.
    pub fn lead(&self, d: f64) -> f64 {
        self.amplitude_m * ((d / self.radius_m + self.phase).sin() - self.phase.sin())
    }
}

/// One drum encoder: scale and offset (truth), backlash, noise and quantisation.
#[derive(Debug, Clone)]
pub struct Encoder {
    drum: Option<Drum>,
    eccentric: Option<Eccentric>,
    scale: f64,
    offset: f64,
    backlash: Backlash,
    sigma: f64,
    quantum: f64,
    winding: Winding,
}

/// A drum's winding irregularity: a fixed, smooth, random function of the paid-out length with
/// RMS `sigma` (m) and correlation length `wavelength` (m): Gaussian values on a lattice of that
/// spacing, joined by smoothsteps, scaled to the RMS. Seeded per cable; deterministic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Winding {
    sigma: f64,
    wavelength: f64,
    seed: u64,
}

impl Winding {
    /// No irregularity.
    pub const NONE: Winding = Winding { sigma: 0.0, wavelength: 1.0, seed: 0 };

    /// The irregularity of `noise` for the drum seeded `seed`.
    pub fn new(noise: &Noise, seed: u64) -> Self {
        Winding { sigma: noise.encoder_winding_m, wavelength: noise.encoder_winding_wavelength_m.max(1e-9), seed }
    }

    /// The irregularity of cable `j`'s drum in a simulation seeded `seed`.
    pub fn of_cable(noise: &Noise, seed: u64, j: usize) -> Self {
        Winding::new(noise, seed ^ (0x5749_4E44 + j as u64))
    }

    /// The departure at paid-out length `d`, m.
    pub fn at(&self, d: f64) -> f64 {
        if self.sigma == 0.0 || !d.is_finite() {
            return 0.0;
        }
        let x = d / self.wavelength;
        let i = x.floor();
        let f = x - i;
        let s = f * f * (3.0 - 2.0 * f);
        let (a, b) = (self.lattice(i as i64), self.lattice(i as i64 + 1));
        // E[((1-s) a + s b)^2] over f is 26/35 for unit lattice values: rescale to sigma.
        self.sigma * (a + s * (b - a)) / (26.0f64 / 35.0).sqrt()
    }

    /// A standard normal value for lattice point `i` (splitmix64 and Box-Muller).
    fn lattice(&self, i: i64) -> f64 {
        let mix = |mut z: u64| {
            z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        let h1 = mix(self.seed ^ (i as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93));
        let h2 = mix(h1);
        let u1 = ((h1 >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        let u2 = (h2 >> 11) as f64 / (1u64 << 53) as f64;
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

impl Encoder {
    /// An encoder reading `scale x length + offset` through a play of `backlash_m`.
    pub fn new(scale: f64, offset: f64, backlash_m: f64, noise: &Noise) -> Self {
        Encoder {
            drum: None,
            eccentric: None,
            scale,
            offset,
            backlash: Backlash::new(backlash_m),
            sigma: noise.encoder_sigma_m,
            quantum: noise.encoder_quantum_m,
            winding: Winding::NONE,
        }
    }

    /// The same encoder on a drum with winding irregularity `winding`.
    pub fn with_winding(mut self, winding: Winding) -> Self {
        self.winding = winding;
        self
    }

    /// The same encoder on a drum with build-up (`None`: a drum of constant radius).
    pub fn with_drum(mut self, drum: Option<Drum>) -> Self {
        self.drum = drum;
        self
    }

    /// The same encoder on an eccentric drum (`None`: a round drum).
    pub fn with_eccentricity(mut self, eccentric: Option<Eccentric>) -> Self {
        self.eccentric = eccentric;
        self
    }

    /// The length the encoder derives from its angle for the paid-out length `y`.
    fn angle_length(&self, y: f64) -> f64 {
        let base = |p: f64| self.drum.map_or(p, |d| d.encoder_length(p));
        match self.eccentric {
            None => base(y),
            // A contraction by amplitude/radius (a few %) per fixed-point step.
            Some(e) => (0..6).fold(base(y), |a, _| base(y - e.lead(a))),
        }
    }

    /// The drum's paid-out length at which a noise-free reading is `reading` (m): what a drive
    /// whose position loop works on the drum's angle holds when commanded `reading` (backlash
    /// aside).
    pub fn drum_for(&self, reading: f64) -> f64 {
        let from_angle = |a: f64| self.drum.map_or(a, |d| d.length(a)) + self.eccentric.map_or(0.0, |e| e.lead(a));
        let mut d = from_angle((reading - self.offset) / self.scale);
        for _ in 0..4 {
            d = from_angle((reading - self.offset - self.winding.at(d)) / self.scale);
        }
        d
    }

    /// Cable `j`'s encoder as the truth and the physics make it: scale, offset, play, drum
    /// build-up and eccentricity, with the noise and winding irregularity of `noise` (the
    /// simulation seeded `seed`).
    pub fn of_cable(truth: &crate::Truth, physics: &crate::Physics, noise: &Noise, seed: u64, j: usize) -> Self {
        Encoder::new(truth.scale[j], truth.l0[j], physics.backlash_m, noise)
            .with_drum(physics.drum())
            .with_eccentricity(physics.eccentricity(j))
            .with_winding(Winding::of_cable(noise, seed, j))
    }

    /// The same encoder with the noise and quantisation of `noise`.
    pub fn with_noise(mut self, noise: &Noise) -> Self {
        self.sigma = noise.encoder_sigma_m;
        self.quantum = noise.encoder_quantum_m;
        self
    }

    /// The reading for the unstretched length `length` (m) paid out by the drum.
    pub fn read(&mut self, length: f64, rng: &mut ChaCha8Rng) -> f64 {
        let y = self.backlash.update(length);
        let e = gauss(rng, 1.0);
        let r = self.scale * self.angle_length(y) + self.offset + self.winding.at(y) + self.sigma * e;
        if self.quantum > 0.0 {
            (r / self.quantum).round() * self.quantum
        } else {
            r
        }
    }
}

/// Speed below which a cable's guides hold it by static friction, m/s: the friction force
/// grows linearly with the speed up to its sliding value at this speed.
pub const FRICTION_STICK_SPEED: f64 = 0.002;

/// The capstan factor between the platform-end tension and the tension at the winch for a cable
/// moving at `speed` (m/s, > 0 paying out) over guides with friction `mu_theta`: `exp(mu theta)`
/// reeling in (the winch pulls the cable through the guides), `exp(-mu theta)` paying out (the
/// guides hold back part of the platform's pull), ramped linearly through zero speed over
/// [`FRICTION_STICK_SPEED`].
pub fn capstan_factor(speed: f64, mu_theta: f64) -> f64 {
    let s = (speed / FRICTION_STICK_SPEED).clamp(-1.0, 1.0);
    (-mu_theta * s).exp()
}

/// One load cell: offset and noise.
#[derive(Debug, Clone)]
pub struct LoadCell {
    /// Constant offset, N.
    pub offset: f64,
    sigma: f64,
}

impl LoadCell {
    /// A load cell with its offset drawn from `noise`.
    pub fn new(noise: &Noise, rng: &mut ChaCha8Rng) -> Self {
        let offset = Normal::new(0.0, noise.loadcell_offset_n.max(0.0)).map(|d| d.sample(rng)).unwrap_or(0.0);
        LoadCell { offset, sigma: noise.loadcell_sigma_n }
    }

    /// A load cell with a known offset and the noise of `noise`.
    pub fn with_offset(offset: f64, noise: &Noise) -> Self {
        LoadCell { offset, sigma: noise.loadcell_sigma_n }
    }

    /// The reading for tension `t`, N.
    pub fn read(&self, t: f64, rng: &mut ChaCha8Rng) -> f64 {
        t + self.offset + gauss(rng, self.sigma)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// The cell at the winch reads more reeling in than paying out, by `exp(+-mu theta)` once the
    /// cable slides, and the plain tension at rest.
    #[test]
    fn capstan_factor_follows_the_direction_of_motion() {
        let c = 0.2f64;
        assert!((capstan_factor(-0.1, c) - c.exp()).abs() < 1e-12);
        assert!((capstan_factor(0.1, c) - (-c).exp()).abs() < 1e-12);
        assert_eq!(capstan_factor(0.0, c), 1.0);
        assert!((capstan_factor(0.5 * FRICTION_STICK_SPEED, c) - (-0.5 * c).exp()).abs() < 1e-12);
        assert_eq!(capstan_factor(0.3, 0.0), 1.0);
    }

    #[test]
    fn backlash_is_a_hysteresis_of_the_play_width() {
        let mut b = Backlash::new(0.002);
        assert_eq!(b.update(1.0), 1.0);
        // Going up: the output lags the input by half the play.
        let up = b.update(1.01);
        assert!((up - (1.01 - 0.001)).abs() < 1e-12);
        // Reversing by less than the play: the output does not move.
        assert_eq!(b.update(1.009), up);
        // Going down: lags by half the play on the other side: total hysteresis = width.
        let down = b.update(1.0);
        assert!((down - 1.001).abs() < 1e-12);
        assert!((up - down - (0.01 - 0.002)).abs() < 1e-12);
    }

    #[test]
    fn tracker_dropouts_and_outliers_have_the_configured_rates() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let noise = Noise::default();
        let mut tr = Tracker::new(&noise);
        let n = 200_000;
        let (mut missing, mut outliers) = (0, 0);
        for _ in 0..n {
            let m = tr.measure([0.0; 3], &mut rng);
            if m[0].is_nan() {
                missing += 1;
            } else if (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt() > 0.02 {
                outliers += 1;
            }
        }
        let (fm, fo) = (missing as f64 / n as f64, outliers as f64 / n as f64);
        assert!((0.0035..0.0065).contains(&fm), "missing {fm}");
        assert!((0.0012..0.0028).contains(&fo), "outliers {fo}");
    }

    /// AR(1) tracker noise keeps the white noise's marginal sigma and has the stated lag-1
    /// correlation; `tracker_phi = 0` is white. 200,000 samples per axis, bounds at 6 standard
    /// errors of each estimate (the variance's with the AR(1) effective sample size
    /// `n (1 - phi^2) / (1 + phi^2)`): failure probability < 1e-8 for correct code.
    #[test]
    fn tracker_ar1_noise_has_the_marginal_sigma_and_the_lag_one_correlation() {
        let n = 200_000;
        for (phi, seed) in [(0.0, 11), (0.5, 12), (0.9, 13)] {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let noise = Noise { tracker_phi: phi, tracker_outlier_prob: 0.0, tracker_dropout_prob: 0.0, ..Noise::default() };
            let sigma = noise.tracker_sigma_m;
            let mut tr = Tracker::new(&noise);
            let x: Vec<[f64; 3]> = (0..n).map(|_| tr.measure([0.0; 3], &mut rng)).collect();
            let nf = n as f64;
            let n_eff = nf * (1.0 - phi * phi) / (1.0 + phi * phi);
            for k in 0..3 {
                let var = x.iter().map(|m| m[k] * m[k]).sum::<f64>() / nf;
                let lag1 = x.windows(2).map(|w| w[0][k] * w[1][k]).sum::<f64>() / (nf - 1.0) / var;
                let ratio = var / (sigma * sigma);
                assert!((ratio - 1.0).abs() < 6.0 * (2.0 / n_eff).sqrt(), "phi {phi} axis {k}: variance ratio {ratio}");
                assert!(
                    (lag1 - phi).abs() < 6.0 * ((1.0 - phi * phi) / nf).sqrt().max(1.0 / nf.sqrt()),
                    "phi {phi} axis {k}: lag-1 {lag1}"
                );
            }
        }
    }
}
