//! Bus faults over real SocketCAN (vcan0, in the VM of `tests/vcan/run`): error frames written
//! as raw `struct can_frame` bytes with `CAN_ERR_FLAG` on a second socket are routed by the CAN
//! core to the master's socket (it sets `CAN_RAW_ERR_FILTER` to all classes), read there as
//! bytes and decoded by the same parser the virtual bus uses; the loop's devices report them as
//! faults naming `vcan0`, and the recoveries. The scenario is `busfault/mod.rs`, shared with
//! `canopen_busfault`.

use crate::busfault;

use socketcan::Socket;
use std::io::Write;
use std::mem::ManuallyDrop;
use std::os::fd::{AsRawFd, FromRawFd};
use std::time::Duration;
use taut_driver::transport::socketcan::SocketCanTransport;
use taut_tests::vcan;
use taut_vdev::{spawn_rack, DriveParams, VirtualDrive};

#[test]
fn bus_faults_reach_the_loop_over_socketcan() {
    let Some(iface) = vcan::iface_or_skip("vcan0", "bus_faults_reach_the_loop_over_socketcan") else {
        return;
    };
    let nodes = [21u8, 22, 23, 24];
    let mut cfg = busfault::robot();
    for (c, &n) in cfg.cables.iter_mut().zip(&nodes) {
        c.drive.as_mut().unwrap().node_id = n;
    }
    let rack =
        spawn_rack(SocketCanTransport::open(iface).unwrap(), nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect());
    let master = SocketCanTransport::open(iface).unwrap();
    let injector = socketcan::CanSocket::open(iface).unwrap();
    // SAFETY: the File only borrows the socket's fd for write(2); ManuallyDrop keeps it from
    // closing the fd, which `injector` owns and outlives it.
    let raw = ManuallyDrop::new(unsafe { std::fs::File::from_raw_fd(injector.as_raw_fd()) });
    let inject = move |b: [u8; 16]| {
        let mut f: &std::fs::File = &raw;
        assert_eq!(f.write(&b).expect("write an error frame on vcan0"), 16);
    };
    busfault::bus_faults_reach_the_loop_with(&cfg, master, iface, inject, Duration::from_secs(60));
    rack.stop();
}
