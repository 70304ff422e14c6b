//! A write buffer that can also seek within what it holds.
//!
//! The `mcap` writer finishes every chunk by asking for its stream position and seeking back to
//! rewrite the chunk's header once the compressed size is known. On a `std::io::BufWriter`
//! every one of those calls flushes the buffer and makes an `lseek` system call: about a dozen
//! system calls per chunk, and we close a chunk after every update. [`SeekBuffer`] serves
//! positions and seeks inside the unflushed tail from memory, so writing an update costs one
//! `write` when it is flushed.
//!
//! It is not a general file abstraction: seeking before the buffered tail flushes the tail and
//! seeks the file itself (the `mcap` writer does that only when it finishes the file).

use std::io::{self, Seek, SeekFrom, Write};

/// Buffers the bytes from file offset `base` on; `pos` is the logical position.
pub struct SeekBuffer<W: Write + Seek> {
    inner: W,
    /// File offset of `buf[0]`; the inner writer is always positioned there.
    base: u64,
    buf: Vec<u8>,
    pos: u64,
    /// The file's length as far as this writer knows: the larger of what the file had before
    /// the buffered tail and the tail's end.
    end: u64,
}

impl<W: Write + Seek> SeekBuffer<W> {
    /// Wraps `inner`, which is positioned at its start and empty (a newly created file).
    pub fn new(inner: W) -> Self {
        Self {
            inner,
            base: 0,
            buf: Vec::with_capacity(1 << 16),
            pos: 0,
            end: 0,
        }
    }

    fn tail_end(&self) -> u64 {
        self.base + self.buf.len() as u64
    }

    /// Writes the buffered tail to the inner writer; afterwards the (empty) tail starts at
    /// `then_at`.
    fn write_out(&mut self, then_at: u64) -> io::Result<()> {
        let inner_at = self.tail_end();
        if !self.buf.is_empty() {
            self.inner.write_all(&self.buf)?;
            self.buf.clear();
        }
        if then_at != inner_at {
            self.inner.seek(SeekFrom::Start(then_at))?;
        }
        self.base = then_at;
        Ok(())
    }
}

impl<W: Write + Seek> Write for SeekBuffer<W> {
    fn write(&mut self, data: &[u8]) -> io::Result<usize> {
        if self.pos < self.base || self.pos > self.tail_end() {
            self.write_out(self.pos)?;
        }
        let at = (self.pos - self.base) as usize;
        let overlap = (self.buf.len() - at).min(data.len());
        self.buf[at..at + overlap].copy_from_slice(&data[..overlap]);
        self.buf.extend_from_slice(&data[overlap..]);
        self.pos += data.len() as u64;
        self.end = self.end.max(self.pos);
        Ok(data.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.write_out(self.pos)?;
        self.inner.flush()
    }
}

impl<W: Write + Seek> Seek for SeekBuffer<W> {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => self.end.checked_add_signed(d),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
        }
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "seek before the start"))?;
        // Outside the tail, the next write flushes and seeks (see `write`).
        self.pos = target;
        Ok(target)
    }

    fn stream_position(&mut self) -> io::Result<u64> {
        Ok(self.pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    /// Counts the inner writer's calls, to show that buffered seeks make none.
    #[derive(Default)]
    struct Counting {
        data: Cursor<Vec<u8>>,
        writes: usize,
        seeks: usize,
    }

    impl Write for Counting {
        fn write(&mut self, b: &[u8]) -> io::Result<usize> {
            self.writes += 1;
            self.data.write(b)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl Seek for Counting {
        fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
            self.seeks += 1;
            self.data.seek(to)
        }
    }

    /// The same operations on a plain cursor, for the expected bytes.
    fn script<W: Write + Seek>(w: &mut W, flush: impl Fn(&mut W)) {
        w.write_all(b"HEADER").unwrap();
        flush(w);
        // A chunk: placeholder header, data, then the header rewritten.
        let start = w.stream_position().unwrap();
        w.write_all(b"????").unwrap();
        w.write_all(b"chunk data").unwrap();
        let end = w.stream_position().unwrap();
        w.seek(SeekFrom::Start(start)).unwrap();
        w.write_all(b"LEN=").unwrap();
        assert_eq!(w.stream_position().unwrap(), start + 4);
        w.seek(SeekFrom::End(0)).unwrap();
        assert_eq!(w.stream_position().unwrap(), end);
        flush(w);
        // Finishing a file: rewrite something before the buffered tail, then append.
        w.seek(SeekFrom::Start(2)).unwrap();
        w.write_all(b"ad").unwrap();
        w.seek(SeekFrom::End(0)).unwrap();
        w.write_all(b"FOOTER").unwrap();
        flush(w);
    }

    #[test]
    fn writes_what_a_plain_file_would_with_one_write_per_flush() {
        let mut plain = Cursor::new(Vec::new());
        script(&mut plain, |_| {});
        let mut b = SeekBuffer::new(Counting::default());
        script(&mut b, |w| w.flush().unwrap());
        assert_eq!(b.inner.data.get_ref(), plain.get_ref());
        assert_eq!(plain.get_ref().as_slice(), b"HEadERLEN=chunk dataFOOTER");
        // Three flushes and the rewrite before the tail: 4 writes; seeks only for the rewrite
        // (there and back).
        assert_eq!(b.inner.writes, 4);
        assert_eq!(b.inner.seeks, 2);
    }
}
