//! Shared helpers for the integration tests.

pub mod mcap;
pub mod vcan;
