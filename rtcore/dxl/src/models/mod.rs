//! The control tables of the supported servos: one static table that the codec, the
//! simulated bus (`dxlsim`) and Python (`_rtcore.model_table()`) all read, so an address or
//! a limit is written down exactly once.
//!
//! Why a Rust static rather than a data file parsed at start-up: the RT loop and the mock
//! bus look items up without allocation or I/O, and a typo fails the build (see the tests),
//! not a run. Runs of identical items (Indirect Address/Data) are stored as one [`Item`] with
//! a `count`, which keeps the tables as short as the e-manual's own notation.
mod tables;

pub use tables::MODELS;

use crate::packet::Protocol;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Read-only: a write answers Access Error.
    R,
    /// Read-write.
    RW,
}

/// One control-table item, or a run of `count` identical items: element `k` sits at
/// `address + k·size`, starts at `default + k·default_step` and is called
/// `"{name} {first_number + k}"` (e.g. "Indirect Address 29").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Item {
    pub name: &'static str,
    pub address: u16,
    /// Bytes per element (1, 2 or 4); multi-byte values are little-endian.
    pub size: u8,
    pub access: Access,
    /// Stored in EEPROM: writable only while Torque Enable is 0 (P2), kept across power cycles.
    pub eeprom: bool,
    /// The value is two's-complement signed (e.g. P2 Present Velocity/Position).
    pub signed: bool,
    /// Initial value, when the e-manual gives one.
    pub default: Option<i64>,
    /// Allowed range of writes (static bounds; some items are further bounded by a Limit item).
    pub min: Option<i64>,
    pub max: Option<i64>,
    /// Physical unit of one count, e.g. "0.229 rev/min"; empty when dimensionless.
    pub unit: &'static str,
    pub count: u16,
    pub default_step: i64,
    /// The e-manual number of a run's first element (1 for single items).
    pub first_number: u16,
}

impl Item {
    /// One past the last byte the item (all its elements) occupies.
    pub fn end(&self) -> u16 {
        self.address + u16::from(self.size) * self.count
    }

    /// The e-manual name of element `k` (the plain name for a single item).
    pub fn element_name(&self, k: u16) -> String {
        if self.count > 1 {
            format!("{} {}", self.name, self.first_number + k)
        } else {
            self.name.to_string()
        }
    }

    /// The initial value of element `k` of a run.
    pub fn default_of(&self, k: u16) -> Option<i64> {
        self.default.map(|d| d + self.default_step * i64::from(k))
    }
}

/// A servo model on one firmware protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Model {
    /// Marketing name without suffixes, e.g. "MX-64" (the same for both firmwares).
    pub name: &'static str,
    /// The value of address 0.
    pub number: u16,
    pub protocol: Protocol,
    pub items: &'static [Item],
}

impl Model {
    pub fn item(&self, name: &str) -> Option<&'static Item> {
        self.items.iter().find(|it| it.name.eq_ignore_ascii_case(name))
    }

    /// The item (and element index within a run) that starts exactly at `address`.
    pub fn item_at(&self, address: u16) -> Option<(&'static Item, u16)> {
        self.items.iter().find_map(|it| {
            let off = address.checked_sub(it.address)?;
            (address < it.end() && off % u16::from(it.size) == 0).then_some((it, off / u16::from(it.size)))
        })
    }

    /// True when every byte of `address..address+len` belongs to some item: the rule a servo
    /// applies before answering a READ or WRITE (otherwise Access Error).
    pub fn covers(&self, address: u16, len: u16) -> bool {
        let end = u32::from(address) + u32::from(len);
        (u32::from(address)..end).all(|a| {
            self.items.iter().any(|it| u32::from(it.address) <= a && a < u32::from(it.end()))
        })
    }

    /// Whether its firmware answers Fast Sync Read (0x8A): the Protocol 2.0 firmwares of the
    /// table (X series, MX(2.0)); Protocol 1.0 has no such instruction. The e-manual lists the
    /// X series; for MX(2.0) it is not confirmed (protocols.md §8), which is why the loop's
    /// `auto` read tries it at start and falls back to Sync Read when it goes unanswered.
    pub fn fast_sync_read(&self) -> bool {
        self.protocol == Protocol::V2
    }

    /// One past the highest address of the table (the size of a byte image of it).
    pub fn table_len(&self) -> u16 {
        self.items.iter().map(Item::end).max().unwrap_or(0)
    }
}

/// The model whose address-0 value is `number`.
pub fn find_by_number(number: u16) -> Option<&'static Model> {
    MODELS.iter().find(|m| m.number == number)
}

/// The model called `name` (case-insensitive, e.g. "mx-64") on firmware `protocol`.
pub fn find_by_name(name: &str, protocol: Protocol) -> Option<&'static Model> {
    MODELS.iter().find(|m| m.protocol == protocol && m.name.eq_ignore_ascii_case(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_model_number_matches_its_model_number_item() {
        for m in MODELS {
            let item = m.item("Model Number").expect(m.name);
            assert_eq!((item.address, item.size, item.default), (0, 2, Some(i64::from(m.number))), "{}", m.name);
        }
    }

    #[test]
    fn items_are_sorted_and_never_overlap() {
        for m in MODELS {
            for pair in m.items.windows(2) {
                assert!(pair[0].end() <= pair[1].address, "{}: {} overlaps {}", m.name, pair[0].name, pair[1].name);
            }
        }
    }

    #[test]
    fn defaults_lie_within_the_ranges() {
        for m in MODELS {
            for it in m.items {
                assert!([1, 2, 4].contains(&it.size), "{} {}", m.name, it.name);
                if let (Some(d), Some(lo), Some(hi)) = (it.default, it.min, it.max) {
                    assert!(lo <= d && d <= hi, "{} {}: {d} not in {lo}..={hi}", m.name, it.name);
                }
                if it.min.is_some_and(|lo| lo < 0) {
                    assert!(it.signed, "{} {}: a negative bound needs a signed item", m.name, it.name);
                }
            }
        }
    }

    #[test]
    fn the_documented_numbers_resolve() {
        let expected = [(29, "MX-28", 1), (30, "MX-28", 2), (310, "MX-64", 1), (311, "MX-64", 2), (320, "MX-106", 1),
            (321, "MX-106", 2), (1020, "XM430-W350", 2), (1200, "XL330-M288", 2)];
        for (number, name, protocol) in expected {
            let m = find_by_number(number).unwrap();
            assert_eq!((m.name, m.protocol.number()), (name, protocol));
            assert_eq!(find_by_name(&name.to_lowercase(), m.protocol).unwrap().number, number);
        }
    }

    #[test]
    fn key_addresses_of_protocols_md() {
        let mx64 = find_by_name("MX-64", Protocol::V2).unwrap();
        for (name, addr, size) in [("Torque Enable", 64, 1), ("Goal Position", 116, 4), ("Present Current", 126, 2),
            ("Present Position", 132, 4), ("Hardware Error Status", 70, 1), ("Current Limit", 38, 2)] {
            let it = mx64.item(name).unwrap();
            assert_eq!((it.address, it.size), (addr, size), "{name}");
        }
        let mx28 = find_by_name("MX-28", Protocol::V1).unwrap();
        for (name, addr, size) in [("Goal Position", 30, 2), ("Present Load", 40, 2), ("Torque Enable", 24, 1)] {
            let it = mx28.item(name).unwrap();
            assert_eq!((it.address, it.size), (addr, size), "{name}");
        }
    }

    #[test]
    fn coverage_follows_the_items() {
        let m = find_by_name("MX-64", Protocol::V2).unwrap();
        assert!(m.covers(132, 4) && m.covers(116, 20));
        assert!(!m.covers(14, 1) && !m.covers(146, 2));
        assert_eq!(m.item_at(172).map(|(it, k)| (it.name, k, it.default_of(k))), Some(("Indirect Address", 2, Some(226))));
        assert!(m.item_at(133).is_none());
        let (run, k) = m.item_at(580).unwrap();
        assert_eq!((run.element_name(k), run.default_of(k)), ("Indirect Address 30".to_string(), Some(635)));
    }
}
