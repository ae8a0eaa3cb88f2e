//! From the `dxl` model table to a simulated servo's control-table layout.
//!
//! The model table is the single source of addresses, sizes, access, defaults and ranges; this
//! module only fills what the e-manual leaves blank, so a simulated servo has a value for
//! every byte:
//! - runs of identical items (Indirect Address 1..56) become one item per element, named as
//!   the e-manual numbers them;
//! - an item without a range accepts whatever its bytes hold (read-only items are never
//!   written by clients anyway);
//! - an item without a default starts at 0, except Firmware Version, which the e-manual does
//!   not state (see `FIRMWARE_VERSION_P1` / `_P2`), and Goal Position, which the servo sets to
//!   its present position at power-up (done by `Servo::new`).
use dxl::models::{self, Access, Model};
use dxl::Protocol;

use crate::table::{representable, ControlTable, Item};

/// The Firmware Version we report for P2 (MX(2.0)) servos. MX(2.0) needs firmware 39 or
/// later and CLEAR arrived in 42; 45 is a release with both, not a measured servo's value.
pub const FIRMWARE_VERSION_P2: i64 = 45;
/// The Firmware Version we report for P1 MX servos (the last P1 MX releases are in the 30s).
pub const FIRMWARE_VERSION_P1: i64 = 36;

/// The model called `name` on `protocol`, or a message listing what exists.
pub fn find_model(name: &str, protocol: Protocol) -> Result<&'static Model, String> {
    models::find_by_name(name, protocol).ok_or_else(|| {
        let known: Vec<&str> =
            models::MODELS.iter().filter(|m| m.protocol == protocol).map(|m| m.name).collect();
        format!("unknown servo model {name:?} for protocol {}: known {}", protocol.number(), known.join(", "))
    })
}

/// A control table at the model's defaults.
pub fn control_table(model: &Model) -> ControlTable {
    let mut items = Vec::new();
    for it in model.items {
        for k in 0..it.count {
            let name = it.element_name(k);
            let (lo, hi) = representable(it.size, it.signed);
            let default = match it.name {
                "Firmware Version" => it.default.unwrap_or(match model.protocol {
                    Protocol::V1 => FIRMWARE_VERSION_P1,
                    Protocol::V2 => FIRMWARE_VERSION_P2,
                }),
                _ => it.default_of(k).unwrap_or(0),
            };
            items.push(Item {
                name,
                address: it.address + u16::from(it.size) * k,
                size: it.size,
                writable: it.access == Access::RW,
                eeprom: it.eeprom,
                default,
                min: it.min.unwrap_or(lo),
                max: it.max.unwrap_or(hi),
            });
        }
    }
    ControlTable::new(items)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_mx_model_builds_with_its_model_number_and_a_firmware_version() {
        for (name, p1, p2) in [("MX-28", 29, 30), ("MX-64", 310, 311), ("MX-106", 320, 321)] {
            for (protocol, number) in [(Protocol::V1, p1), (Protocol::V2, p2)] {
                let table = control_table(find_model(name, protocol).unwrap());
                assert_eq!(table.get("Model Number"), Some(number));
                assert!(table.get("Firmware Version").unwrap() > 0);
                assert_eq!(table.get("Return Delay Time"), Some(250));
            }
        }
    }

    #[test]
    fn runs_become_named_elements() {
        let table = control_table(find_model("MX-64", Protocol::V2).unwrap());
        let item = table.item("Indirect Address 29").unwrap();
        assert_eq!((item.address, item.default), (578, 634));
        assert!(table.item("Indirect Data 56").is_some());
    }

    #[test]
    fn unknown_models_name_the_known_ones() {
        let err = find_model("AX-12", Protocol::V1).unwrap_err();
        assert!(err.contains("MX-64"), "{err}");
    }

    #[test]
    fn signed_read_only_items_hold_negative_values() {
        let mut table = control_table(find_model("MX-64", Protocol::V2).unwrap());
        let k = table.index_of("Present Velocity").unwrap();
        table.store(k, -42);
        assert_eq!(table.value(k), -42);
    }
}
