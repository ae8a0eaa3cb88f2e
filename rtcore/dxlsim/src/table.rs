//! A servo's control table: the byte memory a client reads and writes, with a real servo's rules.
//!
//! The layout (items: address, size, access, EEPROM or RAM, default, min, max) comes from the
//! `dxl` model table, so the mock and the driver agree on every address by construction. This
//! module only enforces the rules of the e-manual (protocols.md §1.3):
//! - a read must start and end inside defined items (reserved gaps in between read as 0, as on
//!   a real servo); otherwise Access Error, and the reply carries no data;
//! - a write must start at an item's first byte and cover each item it touches completely
//!   (otherwise Data Length Error), touch only writable items (otherwise Access Error), leave
//!   EEPROM alone while torque is on when the protocol locks it (Access Error), and keep each value
//!   within the item's min..max (Data Range Error);
//! - a write is all-or-nothing: on any error nothing changes.
//!
//! Values are little-endian; an item whose minimum is negative is read as signed.

/// One control-table item, as the simulation needs it.
#[derive(Clone, Debug, PartialEq)]
pub struct Item {
    pub name: String,
    pub address: u16,
    pub size: u8,
    pub writable: bool,
    pub eeprom: bool,
    pub default: i64,
    pub min: i64,
    pub max: i64,
}

impl Item {
    fn end(&self) -> usize {
        self.address as usize + self.size as usize
    }

    fn signed(&self) -> bool {
        self.min < 0
    }

    /// The smallest and largest values its bytes can hold.
    fn representable(&self) -> (i64, i64) {
        representable(self.size, self.signed())
    }

    /// Decodes this item's little-endian value from its bytes.
    pub(crate) fn decode(&self, bytes: &[u8]) -> i64 {
        let mut raw = 0u64;
        for (i, b) in bytes.iter().enumerate() {
            raw |= (*b as u64) << (8 * i);
        }
        let bits = 8 * self.size as u32;
        if self.signed() && bits < 64 && raw & (1 << (bits - 1)) != 0 {
            (raw | (u64::MAX << bits)) as i64
        } else {
            raw as i64
        }
    }
}

/// Why a table access failed; the bus turns it into the protocol's error byte.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TableError {
    /// Undefined address, read-only item, or EEPROM while torque is on.
    Access,
    /// The write does not cover whole items.
    Length,
    /// A value outside its item's min..max.
    Range,
    /// A goal outside the servo's configured Limit item (checked by the servo, not the table:
    /// the limit is another item's current value).
    Limit,
}

/// The memory of one servo.
#[derive(Clone, Debug)]
pub struct ControlTable {
    items: Vec<Item>,
    /// For each byte address, the index of the item it belongs to.
    owner: Vec<Option<u16>>,
    memory: Vec<u8>,
}

impl ControlTable {
    /// Builds the table from its items, each set to its default value.
    pub fn new(mut items: Vec<Item>) -> ControlTable {
        items.sort_by_key(|i| i.address);
        let size = items.iter().map(Item::end).max().unwrap_or(0);
        let mut owner = vec![None; size];
        for (k, item) in items.iter().enumerate() {
            for slot in &mut owner[item.address as usize..item.end()] {
                *slot = Some(k as u16);
            }
        }
        let mut table = ControlTable { items, owner, memory: vec![0; size] };
        table.reset_to_defaults();
        table
    }

    /// Every item back to its default: a factory reset.
    pub fn reset_to_defaults(&mut self) {
        self.load_defaults(false);
    }

    /// RAM items back to their defaults, EEPROM untouched: what a reboot does.
    pub fn reload_ram(&mut self) {
        self.load_defaults(true);
    }

    fn load_defaults(&mut self, ram_only: bool) {
        for item in self.items.iter().filter(|i| !(ram_only && i.eeprom)) {
            store(&mut self.memory, item.address, item.size, item.default);
        }
    }

    pub fn items(&self) -> &[Item] {
        &self.items
    }

    /// The item called `name`, if the model has it.
    pub fn item(&self, name: &str) -> Option<&Item> {
        self.items.iter().find(|i| i.name == name)
    }

    /// A client read of `len` bytes at `address`.
    pub fn read(&self, address: u16, len: u16) -> Result<&[u8], TableError> {
        let start = address as usize;
        let end = start + len as usize;
        if len == 0 || !self.defined(start) || !self.defined(end - 1) {
            return Err(TableError::Access);
        }
        Ok(&self.memory[start..end])
    }

    /// A client write of `data` at `address`; `eeprom_locked` is true when torque is on and
    /// the protocol forbids EEPROM writes then.
    pub fn write(&mut self, address: u16, data: &[u8], eeprom_locked: bool) -> Result<(), TableError> {
        let start = address as usize;
        let end = start + data.len();
        if data.is_empty() || end > self.owner.len() {
            return Err(TableError::Access);
        }
        let mut pos = start;
        while pos < end {
            let item = &self.items[self.owner[pos].ok_or(TableError::Access)? as usize];
            if item.address as usize != pos {
                return Err(TableError::Length);
            }
            if !item.writable || (item.eeprom && eeprom_locked) {
                return Err(TableError::Access);
            }
            if item.end() > end {
                return Err(TableError::Length);
            }
            let value = item.decode(&data[pos - start..item.end() - start]);
            if value < item.min || value > item.max {
                return Err(TableError::Range);
            }
            pos = item.end();
        }
        self.memory[start..end].copy_from_slice(data);
        Ok(())
    }

    /// The position of the item called `name` in `items()`: resolve once, then use `value`
    /// and `store` on the hot path.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.items.iter().position(|i| i.name == name)
    }

    /// The value of the item at `index` (the simulation's own access: no rules apply).
    pub fn value(&self, index: usize) -> i64 {
        let item = &self.items[index];
        item.decode(&self.memory[item.address as usize..item.end()])
    }

    /// Sets the item at `index`, saturated to what its bytes can hold (the firmware's own
    /// access: it may write read-only items, and it never wraps a large reading around).
    pub fn store(&mut self, index: usize, value: i64) {
        let item = &self.items[index];
        let (lo, hi) = item.representable();
        let (address, size) = (item.address, item.size);
        store(&mut self.memory, address, size, value.clamp(lo, hi));
    }

    /// The value of an item by name.
    pub fn get(&self, name: &str) -> Option<i64> {
        self.index_of(name).map(|k| self.value(k))
    }

    /// Sets an item's value as a client write would, with the write rules (used for initial
    /// register overrides from configuration, so a bad value is refused, not clamped).
    pub fn set_checked(&mut self, name: &str, value: i64) -> Result<(), TableError> {
        let index = self.index_of(name).ok_or(TableError::Access)?;
        let item = &self.items[index];
        if value < item.min || value > item.max {
            return Err(TableError::Range);
        }
        self.store(index, value);
        Ok(())
    }

    fn defined(&self, address: usize) -> bool {
        self.owner.get(address).is_some_and(Option::is_some)
    }
}

/// The smallest and largest values `size` little-endian bytes hold (sizes above 4 are
/// treated as 4: no control-table item is wider).
pub fn representable(size: u8, signed: bool) -> (i64, i64) {
    let bits = 8 * u32::from(size.clamp(1, 4));
    if signed {
        (-(1i64 << (bits - 1)), (1i64 << (bits - 1)) - 1)
    } else {
        (0, (1i64 << bits) - 1)
    }
}

fn store(memory: &mut [u8], address: u16, size: u8, value: i64) {
    let bytes = value.to_le_bytes();
    let start = address as usize;
    memory[start..start + size as usize].copy_from_slice(&bytes[..size as usize]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn item(name: &str, address: u16, size: u8, writable: bool, eeprom: bool, min: i64, max: i64) -> Item {
        Item { name: name.into(), address, size, writable, eeprom, default: min.max(0), min, max }
    }

    /// A miniature P2-like layout: EEPROM at 0..12, a gap, RAM from 64.
    fn table() -> ControlTable {
        ControlTable::new(vec![
            Item { default: 311, ..item("Model Number", 0, 2, false, true, 0, 65535) },
            item("ID", 7, 1, true, true, 0, 252),
            item("Return Delay Time", 9, 1, true, true, 0, 254),
            item("Torque Enable", 64, 1, true, false, 0, 1),
            item("LED", 65, 1, true, false, 0, 1),
            item("Goal Position", 116, 4, true, false, -1_048_575, 1_048_575),
            item("Present Position", 132, 4, false, false, i32::MIN as i64, i32::MAX as i64),
        ])
    }

    #[test]
    fn defaults_are_loaded_and_read_back_little_endian() {
        let t = table();
        assert_eq!(t.read(0, 2).unwrap(), &[0x37, 0x01]);
        assert_eq!(t.get("Model Number"), Some(311));
    }

    #[test]
    fn reads_need_defined_first_and_last_bytes_but_span_gaps() {
        let t = table();
        assert_eq!(t.read(0, 10).unwrap().len(), 10);
        assert_eq!(t.read(2, 1), Err(TableError::Access));
        assert_eq!(t.read(64, 3), Err(TableError::Access));
        assert_eq!(t.read(200, 1), Err(TableError::Access));
        assert_eq!(t.read(0, 0), Err(TableError::Access));
    }

    #[test]
    fn write_rules_match_the_e_manual() {
        let mut t = table();
        assert_eq!(t.write(0, &[1, 2], false), Err(TableError::Access), "read-only");
        assert_eq!(t.write(30, &[1], false), Err(TableError::Access), "undefined");
        assert_eq!(t.write(7, &[3], true), Err(TableError::Access), "EEPROM while torque on");
        assert_eq!(t.write(7, &[253], false), Err(TableError::Range));
        assert_eq!(t.write(116, &[0, 2], false), Err(TableError::Length), "half an item");
        assert_eq!(t.write(117, &[0, 2, 0], false), Err(TableError::Length), "mid-item start");
        assert_eq!(t.write(64, &[1, 1], true), Ok(()), "two RAM items in one write");
        assert_eq!(t.get("LED"), Some(1));
        assert_eq!(t.write(7, &[3], false), Ok(()));
        assert_eq!(t.get("ID"), Some(3));
    }

    #[test]
    fn signed_items_accept_negative_values_in_range() {
        let mut t = table();
        t.write(116, &(-1000i32).to_le_bytes(), false).unwrap();
        assert_eq!(t.get("Goal Position"), Some(-1000));
        assert_eq!(t.write(116, &(-2_000_000i32).to_le_bytes(), false), Err(TableError::Range));
    }

    #[test]
    fn reload_ram_keeps_eeprom() {
        let mut t = table();
        t.write(9, &[0], false).unwrap();
        t.write(64, &[1], false).unwrap();
        t.reload_ram();
        assert_eq!(t.get("Return Delay Time"), Some(0));
        assert_eq!(t.get("Torque Enable"), Some(0));
    }

    proptest! {
        #[test]
        fn a_failed_write_changes_nothing(address in 0u16..140, data in proptest::collection::vec(any::<u8>(), 1..12)) {
            let mut t = table();
            let before = t.read(0, 136).unwrap().to_vec();
            if t.write(address, &data, true).is_err() {
                prop_assert_eq!(t.read(0, 136).unwrap(), &before[..]);
            }
        }

        #[test]
        fn successful_writes_read_back(value in -1_048_575i32..=1_048_575) {
            let mut t = table();
            t.write(116, &value.to_le_bytes(), true).unwrap();
            prop_assert_eq!(t.read(116, 4).unwrap(), &value.to_le_bytes()[..]);
        }
    }
}
