//! Virtual devices on the same transports as the real ones (filled by the devices work).
pub mod drive;
pub mod loadcell;
pub mod tracker;
