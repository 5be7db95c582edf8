//! The object dictionary: what each index and sub-index reads and accepts (module
//! documentation of `drive` for the table and the abort codes).

use super::sdo_server::SDO_MAX;
use super::VirtualDrive;
use taut_proto::canopen::od;
use taut_proto::canopen::sdo::AbortCode;

/// Following error actual value, counts.
pub(super) const FOLLOWING_ERROR: u16 = 0x60F4;

impl VirtualDrive {
    pub(super) fn read(&self, index: u16, sub: u8) -> Result<([u8; SDO_MAX], usize), AbortCode> {
        let mut b = [0u8; SDO_MAX];
        let mut put = |bytes: &[u8]| {
            b[..bytes.len()].copy_from_slice(bytes);
            Ok((b, bytes.len()))
        };
        match (index, sub) {
            (od::DEVICE_TYPE, 0) => put(&od::DEVICE_TYPE_CIA402_SERVO.to_le_bytes()),
            (od::DEVICE_NAME, 0) => {
                let n = self.p.name.len().min(SDO_MAX);
                put(&self.p.name.as_bytes()[..n])
            }
            (od::HEARTBEAT_PRODUCER, 0) => put(&self.heartbeat_ms.to_le_bytes()),
            (od::HEARTBEAT_CONSUMER, 0) => put(&[1]),
            (od::HEARTBEAT_CONSUMER, 1) => put(&self.hb_consumer.to_le_bytes()),
            (od::ABORT_CONNECTION, 0) => put(&self.abort_option.to_le_bytes()),
            (od::IDENTITY, 0) => put(&[4]),
            (od::IDENTITY, 1) => put(&self.p.vendor_id.to_le_bytes()),
            (od::IDENTITY, 2) => put(&self.p.product_code.to_le_bytes()),
            (od::IDENTITY, 3) => put(&self.p.revision.to_le_bytes()),
            (od::IDENTITY, 4) => put(&self.p.serial.to_le_bytes()),
            (0x1400..=0x1403, _) | (0x1800..=0x1803, _) => {
                let slot = if index < 0x1800 { &self.rpdo[usize::from(index - 0x1400)] } else { &self.tpdo[usize::from(index - 0x1800)] };
                match sub {
                    0 => put(&[2]),
                    1 => put(&slot.cob_id.to_le_bytes()),
                    2 => put(&[slot.trans_type]),
                    _ => Err(AbortCode::NO_SUBINDEX),
                }
            }
            (0x1600..=0x1603, _) | (0x1A00..=0x1A03, _) => {
                let slot = if index < 0x1A00 { &self.rpdo[usize::from(index - 0x1600)] } else { &self.tpdo[usize::from(index - 0x1A00)] };
                match sub {
                    0 => put(&[slot.count]),
                    1..=8 => put(&slot.map[usize::from(sub - 1)].to_le_bytes()),
                    _ => Err(AbortCode::NO_SUBINDEX),
                }
            }
            (0x2000, 0) => put(&self.scratch[..self.scratch_len]),
            (od::ERROR_CODE, 0) => put(&self.error_code.to_le_bytes()),
            (od::CONTROLWORD, 0) => put(&self.controlword.to_le_bytes()),
            (od::STATUSWORD, 0) => put(&self.statusword().to_le_bytes()),
            (od::MODES_OF_OPERATION, 0) => put(&[self.mode as u8]),
            (od::MODES_OF_OPERATION_DISPLAY, 0) => put(&[self.mode as u8]),
            (od::POSITION_ACTUAL, 0) => put(&self.position().to_le_bytes()),
            (od::TARGET_TORQUE, 0) => put(&self.target_torque.to_le_bytes()),
            (od::TORQUE_ACTUAL, 0) => put(&self.torque.to_le_bytes()),
            (od::TARGET_POSITION, 0) => put(&self.target_position.to_le_bytes()),
            (od::VELOCITY_ACTUAL, 0) => put(&self.velocity.to_le_bytes()),
            (FOLLOWING_ERROR, 0) => put(&self.target_position.wrapping_sub(self.position()).to_le_bytes()),
            (0x1000 | 0x1008 | 0x1016 | 0x1017 | 0x1018 | 0x2000 | 0x6007 | 0x603F..=0x60F4, _) if object_exists(index) => {
                Err(AbortCode::NO_SUBINDEX)
            }
            _ => Err(AbortCode::NO_OBJECT),
        }
    }

    pub(super) fn write(&mut self, index: u16, sub: u8, d: &[u8]) -> Result<(), AbortCode> {
        let u = |d: &[u8], n: usize| -> Result<u32, AbortCode> {
            if d.len() != n {
                return Err(AbortCode::LENGTH_MISMATCH);
            }
            let mut b = [0u8; 4];
            b[..n].copy_from_slice(d);
            Ok(u32::from_le_bytes(b))
        };
        match (index, sub) {
            (od::HEARTBEAT_PRODUCER, 0) => {
                self.heartbeat_ms = u(d, 2)? as u16;
                self.next_hb = None;
                Ok(())
            }
            (od::HEARTBEAT_CONSUMER, 1) => {
                let v = u(d, 4)?;
                // Bits 24..31 reserved, node id 1..=127 when a time is given (CiA 301 7.5.2.36).
                let node = (v >> 16) & 0xFF;
                if v >> 24 != 0 || (v & 0xFFFF != 0 && !(1..=127).contains(&node)) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.hb_consumer = v;
                // Monitoring starts again at the producer's next heartbeat.
                self.consumer_last = None;
                self.consumer_lost = false;
                Ok(())
            }
            (od::HEARTBEAT_CONSUMER, 0) => Err(AbortCode::READ_ONLY),
            (od::ABORT_CONNECTION, 0) => {
                let v = u(d, 2)? as u16 as i16;
                if !(0..=3).contains(&v) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.abort_option = v;
                Ok(())
            }
            (0x1400..=0x1403, _) | (0x1800..=0x1803, _) => {
                let rx = index < 0x1800;
                let slot = if rx { &mut self.rpdo[usize::from(index - 0x1400)] } else { &mut self.tpdo[usize::from(index - 0x1800)] };
                let v = match sub {
                    1 => u(d, 4)?,
                    2 => u(d, 1)?,
                    _ => 0,
                };
                slot.write_comm(sub, v)
            }
            (0x1600..=0x1603, _) | (0x1A00..=0x1A03, _) => {
                let rx = index < 0x1A00;
                let slot = if rx { &mut self.rpdo[usize::from(index - 0x1600)] } else { &mut self.tpdo[usize::from(index - 0x1A00)] };
                let v = match sub {
                    0 => u(d, 1)?,
                    1..=8 => u(d, 4)?,
                    _ => 0,
                };
                slot.write_map(rx, sub, v)
            }
            (0x2000, 0) => {
                if d.len() > self.scratch.len() {
                    return Err(AbortCode(0x0607_0012));
                }
                self.scratch[..d.len()].copy_from_slice(d);
                self.scratch_len = d.len();
                Ok(())
            }
            (od::CONTROLWORD, 0) => {
                let v = u(d, 2)? as u16;
                self.on_controlword(v);
                Ok(())
            }
            (od::MODES_OF_OPERATION, 0) => {
                let v = u(d, 1)? as u8 as i8;
                if !matches!(v, 8 | 10) {
                    return Err(AbortCode::INVALID_VALUE);
                }
                self.mode = v;
                Ok(())
            }
            (od::TARGET_TORQUE, 0) => {
                self.target_torque = u(d, 2)? as u16 as i16;
                Ok(())
            }
            (od::TARGET_POSITION, 0) => {
                self.target_position = u(d, 4)? as i32;
                Ok(())
            }
            (0x1000 | 0x1008 | 0x1018 | 0x603F | 0x6041 | 0x6061 | 0x6064 | 0x606C | 0x6077 | 0x60F4, _) => Err(AbortCode::READ_ONLY),
            _ if object_exists(index) => Err(AbortCode::NO_SUBINDEX),
            _ => Err(AbortCode::NO_OBJECT),
        }
    }
}

/// Whether object `index` is in this drive's dictionary (the table in the module documentation).
/// One list for the SDO server and the PDO mapping check, so that an object the drive has but
/// cannot map is refused as not mappable (0x06040041), not as missing (0x06020000).
pub(super) fn object_exists(index: u16) -> bool {
    matches!(
        index,
        0x1000
            | 0x1008
            | 0x1016
            | 0x1017
            | 0x1018
            | 0x1400..=0x1403
            | 0x1600..=0x1603
            | 0x1800..=0x1803
            | 0x1A00..=0x1A03
            | 0x2000
            | 0x6007
            | 0x603F
            | 0x6040
            | 0x6041
            | 0x6060
            | 0x6061
            | 0x6064
            | 0x606C
            | 0x6071
            | 0x6077
            | 0x607A
            | 0x60F4
    )
}
