//! Byte stuffing: after every `FF FF FD` in the instruction..params range, an extra `FD`
//! is inserted so the body can never look like a header. One small state machine tracks how
//! much of `FF FF FD` the last bytes matched; the encoder and decoder both use it, so they
//! agree by construction.

/// How many bytes of `FF FF FD` the stream has just matched (0..=3).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PatternMatcher(u8);

impl PatternMatcher {
    /// Feed one byte; true when the last three bytes are `FF FF FD`.
    pub(crate) fn feed(&mut self, b: u8) -> bool {
        self.0 = match (self.0, b) {
            (1 | 2, 0xFF) => 2,
            (_, 0xFF) => 1,
            (2, 0xFD) => 3,
            _ => 0,
        };
        self.0 == 3
    }

    pub(crate) fn matched(self) -> bool {
        self.0 == 3
    }

    pub(crate) fn reset(&mut self) {
        self.0 = 0;
    }
}

/// Stuffed size of `src`.
pub fn stuffed_len(src: &[u8]) -> usize {
    stuffed_len_of(src.iter().copied())
}

/// Stuffed size of a byte sequence given in pieces (instruction, error, params).
pub fn stuffed_len_of(src: impl IntoIterator<Item = u8>) -> usize {
    let mut m = PatternMatcher::default();
    src.into_iter().map(|b| if m.feed(b) { m.reset(); 2 } else { 1 }).sum()
}

/// Stuff `src` into `dst`; returns the bytes written, or `None` when `dst` is too short.
pub fn stuff(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    let mut m = PatternMatcher::default();
    let mut n = 0;
    for &b in src {
        *dst.get_mut(n)? = b;
        n += 1;
        if m.feed(b) {
            *dst.get_mut(n)? = 0xFD;
            n += 1;
            m.reset();
        }
    }
    Some(n)
}

/// Remove stuffing from `src` into `dst` (which must be at least `src.len()` long, since
/// unstuffing never grows); returns the bytes written.
pub fn unstuff(src: &[u8], dst: &mut [u8]) -> usize {
    let mut m = PatternMatcher::default();
    let mut n = 0;
    for &b in src {
        if m.matched() && b == 0xFD {
            m.reset();
            continue;
        }
        dst[n] = b;
        n += 1;
        m.feed(b);
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stuffs_the_documented_example() {
        let mut out = [0u8; 8];
        let n = stuff(&[0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]);
    }

    #[test]
    fn a_literal_fd_after_the_pattern_survives() {
        let src = [0xFF, 0xFF, 0xFD, 0xFD, 0xFF, 0xFF, 0xFF, 0xFD];
        let mut st = [0u8; 16];
        let n = stuff(&src, &mut st).unwrap();
        assert_eq!(n, stuffed_len(&src));
        let mut back = [0u8; 16];
        let m = unstuff(&st[..n], &mut back);
        assert_eq!(&back[..m], &src);
    }
}
