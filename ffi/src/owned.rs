//! Plugin-owned devices for C hosts (`TAUT_DEVICES_PLUGIN`): the devices of the robot
//! configuration, brought up by `taut_activate` exactly as `taut start` does on hardware.

use taut_config::RobotConfig;
use taut_rt_core::io::Devices;
use taut_rt_core::plugin::DeviceSource;
use taut_rt_core::robot_io::{BringUpError, Peripherals, RobotDevices};

/// The CANopen drives on the configuration's SocketCAN interface, its Modbus load cells and
/// its tracker port.
pub(crate) struct ConfigDevices {
    cfg: RobotConfig,
}

impl ConfigDevices {
    pub(crate) fn new(cfg: &RobotConfig) -> ConfigDevices {
        ConfigDevices { cfg: cfg.clone() }
    }
}

impl DeviceSource for ConfigDevices {
    #[cfg(target_os = "linux")]
    fn bring_up(&mut self) -> Result<Box<dyn Devices>, BringUpError> {
        use taut_driver::transport::socketcan::SocketCanTransport;
        let err = |what: &str, message: String| BringUpError { what: what.into(), message };
        let Some(can) = &self.cfg.can else {
            return Err(err("can", "plugin-owned devices need a [can] table with the interface of the drives".into()));
        };
        let bus = SocketCanTransport::open(&can.interface)
            .map_err(|e| err("can.interface", format!("{}: {e} (is it up? `ip link set {} up`)", can.interface, can.interface)))?;
        let peripherals = Peripherals::from_config(&self.cfg)?;
        Ok(Box::new(RobotDevices::bring_up(&self.cfg, bus, peripherals)?))
    }

    #[cfg(not(target_os = "linux"))]
    fn bring_up(&mut self) -> Result<Box<dyn Devices>, BringUpError> {
        Err(BringUpError { what: "can".into(), message: "plugin-owned devices need SocketCAN (Linux)".into() })
    }
}
