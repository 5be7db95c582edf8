//! Virtual devices on the same transports as the real ones (filled by the devices work).
pub mod loadcell;
pub mod tracker;
