//! Which cables follow in torque: the one rule the controller, the drive set-up, the simulator
//! and the calibration share.
//!
//! A point mass has three degrees of freedom, so three cables in position mode fix it; any
//! further cable runs in torque mode at a set tension (a *follower*), so that errors in the
//! parameters do not make position-controlled cables fight. During the initialisation the
//! three cables of the current phase ([`crate::runtime::MotionConfig::init_phases`]) are the
//! held ones; otherwise cables `0..HELD` are.

/// How many cables hold the platform in position.
pub const HELD: usize = 3;

/// The cables held in position outside the initialisation phases.
pub const OPERATION_HELD: [usize; HELD] = [0, 1, 2];

/// True when cable `j` follows in torque while the cables `held` hold the platform.
pub fn follows(j: usize, held: &[usize]) -> bool {
    !held.contains(&j)
}

/// True when cable `j` follows in torque in operation (controller, excitation, holding).
pub fn follows_in_operation(j: usize) -> bool {
    follows(j, &OPERATION_HELD)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_held_the_rest_follow() {
        assert_eq!((0..6).map(follows_in_operation).collect::<Vec<_>>(), [false, false, false, true, true, true]);
        assert_eq!((0..4).map(|j| follows(j, &[1, 2, 3])).collect::<Vec<_>>(), [true, false, false, false]);
    }
}
