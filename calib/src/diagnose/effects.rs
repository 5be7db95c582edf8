//! The effect library as the diagnosis names it: see [`crate::effects`].

pub use crate::effects::*;
