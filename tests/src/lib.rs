//! Shared helpers for the integration tests.

pub mod honesty;
pub mod mcap;
pub mod sim;
pub mod startup;
pub mod vcan;
