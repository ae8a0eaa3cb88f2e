//! The byte buffer behind both streaming decoders: a fixed slab allocated once, filled by
//! `push`, drained from the front, compacted in place. Fixed capacity (not a growing `Vec`)
//! keeps the decoders allocation-free after construction, which the RT loop relies on.

pub(crate) struct ByteStream {
    buf: Box<[u8]>,
    start: usize,
    end: usize,
    skipped: u64,
}

impl ByteStream {
    pub(crate) fn with_capacity(capacity: usize) -> Self {
        ByteStream { buf: vec![0; capacity].into_boxed_slice(), start: 0, end: 0, skipped: 0 }
    }

    /// Append as many bytes as fit; returns how many were taken.
    pub(crate) fn push(&mut self, bytes: &[u8]) -> usize {
        if self.buf.len() - self.end < bytes.len() && self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let n = bytes.len().min(self.buf.len() - self.end);
        self.buf[self.end..self.end + n].copy_from_slice(&bytes[..n]);
        self.end += n;
        n
    }

    pub(crate) fn pending(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    /// Drop `n` bytes that formed a packet.
    pub(crate) fn consume(&mut self, n: usize) {
        self.start += n.min(self.end - self.start);
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        }
    }

    /// Drop `n` bytes of garbage, counting them.
    pub(crate) fn skip(&mut self, n: usize) {
        let n = n.min(self.end - self.start);
        self.skipped += n as u64;
        self.consume(n);
    }

    /// Skip (and count) bytes until `header` starts the pending data; true when it does,
    /// false when more bytes are needed (a partial header at the end is kept).
    pub(crate) fn seek_header(&mut self, header: &[u8]) -> bool {
        match find_header(self.pending(), header) {
            HeaderSearch::Found(i) => {
                self.skip(i);
                true
            }
            HeaderSearch::Partial(i) => {
                self.skip(i);
                false
            }
            HeaderSearch::None => {
                self.skip(self.end - self.start);
                false
            }
        }
    }

    pub(crate) fn skipped(&self) -> u64 {
        self.skipped
    }

    pub(crate) fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
    }

    pub(crate) fn capacity(&self) -> usize {
        self.buf.len()
    }
}

/// Where a header may begin in `data`: `Found(i)` for a full match at `i`, `Partial(i)` when a
/// prefix of the header runs to the end of `data` at `i` (keep it, wait for more bytes), or
/// `None` when no byte can start a header.
enum HeaderSearch {
    Found(usize),
    Partial(usize),
    None,
}

fn find_header(data: &[u8], header: &[u8]) -> HeaderSearch {
    for i in 0..data.len() {
        let tail = &data[i..];
        let n = tail.len().min(header.len());
        if tail[..n] == header[..n] {
            return if n == header.len() { HeaderSearch::Found(i) } else { HeaderSearch::Partial(i) };
        }
    }
    HeaderSearch::None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_compacts_and_reports_what_fit() {
        let mut s = ByteStream::with_capacity(4);
        assert_eq!(s.push(&[1, 2, 3]), 3);
        s.consume(2);
        assert_eq!(s.push(&[4, 5, 6, 7]), 3);
        assert_eq!(s.pending(), &[3, 4, 5, 6]);
    }

    #[test]
    fn header_search_keeps_a_partial_prefix() {
        assert!(matches!(find_header(&[9, 0xFF, 0xFF], &[0xFF, 0xFF, 0xFD]), HeaderSearch::Partial(1)));
        assert!(matches!(find_header(&[9, 0xFF, 0xFF, 0xFD], &[0xFF, 0xFF, 0xFD]), HeaderSearch::Found(1)));
        assert!(matches!(find_header(&[9, 8], &[0xFF, 0xFF]), HeaderSearch::None));
    }
}
