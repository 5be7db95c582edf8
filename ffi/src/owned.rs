//! Plugin-owned devices for C hosts (`TAUT_DEVICES_PLUGIN`): the devices of the robot
//! configuration, brought up by `taut_activate` exactly as `taut start` does on hardware.

use taut_config::RobotConfig;
use taut_io::robot_io::{BringUpError, Peripherals, RobotDevices};
use taut_plugin::DeviceSource;
use taut_rt::io::Devices;

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
        let Some(can) = &self.cfg.can else { return Err(BringUpError::NoCan) };
        let bus = SocketCanTransport::open(&can.interface).map_err(|source| BringUpError::CanInterface {
            interface: can.interface.clone(),
            bitrate: can.bitrate,
            source,
        })?;
        let peripherals = Peripherals::from_config(&self.cfg)?;
        Ok(Box::new(RobotDevices::bring_up(&self.cfg, bus, peripherals)?))
    }

    #[cfg(not(target_os = "linux"))]
    fn bring_up(&mut self) -> Result<Box<dyn Devices>, BringUpError> {
        Err(BringUpError::Unsupported)
    }
}
