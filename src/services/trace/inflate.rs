//! A gzip stream inflated on a thread of its own: the trace reader parses one block while the
//! next is inflated. Reading a moving hour, inflating was a sixth of the reader's work, and the
//! reader is what bounds a replay (its consumer, the replay's programs, runs on a third thread).

use std::io::{self, BufRead, Read};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

/// How much one block holds: large enough that handing it over costs nothing, small enough that
/// the first one comes at once.
const BLOCK: usize = 1 << 18;

/// The inflated bytes of a gzip stream, as a [`BufRead`] over the blocks the inflating thread
/// hands over (read in place: no copy into another buffer);
/// an error of the stream (a truncated file's `UnexpectedEof` among them) comes after the bytes
/// that preceded it, with its kind.
pub struct Inflated {
    rx: Receiver<io::Result<Vec<u8>>>,
    back: SyncSender<Vec<u8>>,
    block: Vec<u8>,
    at: usize,
    ended: bool,
}

impl Inflated {
    /// Starts inflating `compressed` (one or more gzip members) on a new thread. The thread
    /// ends at the stream's end, at its first error, or once this reader is dropped.
    pub fn start(compressed: impl Read + Send + 'static) -> io::Result<Inflated> {
        let (tx, rx) = sync_channel::<io::Result<Vec<u8>>>(4);
        let (back, returned) = sync_channel::<Vec<u8>>(4);
        std::thread::Builder::new()
            .name("trace-inflate".into())
            .spawn(move || {
                let mut gz = flate2::read::MultiGzDecoder::new(io::BufReader::with_capacity(1 << 16, compressed));
                loop {
                    let mut block = returned.try_recv().unwrap_or_else(|_| Vec::with_capacity(BLOCK));
                    block.resize(BLOCK, 0);
                    let mut filled = 0;
                    let mut failed = None;
                    while filled < BLOCK {
                        match gz.read(&mut block[filled..]) {
                            Ok(0) => break,
                            Ok(n) => filled += n,
                            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                            Err(e) => {
                                failed = Some(e);
                                break;
                            }
                        }
                    }
                    block.truncate(filled);
                    let end = filled < BLOCK;
                    // A reader that was dropped has closed its end: then this ends too.
                    if filled > 0 && tx.send(Ok(block)).is_err() {
                        return;
                    }
                    if let Some(e) = failed {
                        let _ = tx.send(Err(e));
                        return;
                    }
                    if end {
                        return;
                    }
                }
            })?;
        Ok(Inflated {
            rx,
            back,
            block: Vec::new(),
            at: 0,
            ended: false,
        })
    }
}

impl BufRead for Inflated {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        while self.at == self.block.len() && !self.ended {
            match self.rx.recv() {
                Ok(Ok(next)) => {
                    // The finished block goes back for reuse; should the thread be gone, it is
                    // simply freed.
                    let done = std::mem::replace(&mut self.block, next);
                    let _ = self.back.try_send(done);
                    self.at = 0;
                }
                Ok(Err(e)) => {
                    self.ended = true;
                    return Err(e);
                }
                // The thread ended after its last block.
                Err(_) => self.ended = true,
            }
        }
        Ok(&self.block[self.at..])
    }

    fn consume(&mut self, n: usize) {
        self.at = (self.at + n).min(self.block.len());
    }
}

impl Read for Inflated {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        let block = self.fill_buf()?;
        let n = out.len().min(block.len());
        out[..n].copy_from_slice(&block[..n]);
        self.consume(n);
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn gzip(data: &[u8]) -> Vec<u8> {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(data).expect("in memory");
        e.finish().expect("in memory")
    }

    #[test]
    fn it_reads_what_was_compressed_over_many_blocks_and_members() {
        let data: Vec<u8> = (0..3 * BLOCK + 12_345).map(|i| (i % 251) as u8).collect();
        let mut two = gzip(&data);
        two.extend(gzip(b"and a second member"));
        let mut out = Vec::new();
        Inflated::start(io::Cursor::new(two))
            .expect("thread")
            .read_to_end(&mut out)
            .expect("whole");
        assert_eq!(&out[..data.len()], &data[..]);
        assert_eq!(&out[data.len()..], b"and a second member");
    }

    #[test]
    fn a_truncated_stream_gives_its_bytes_then_unexpected_eof() {
        let data = vec![b'x'; 2 * BLOCK];
        let whole = gzip(&data);
        // Without the trailer (8 bytes) and a little more.
        let cut = whole[..whole.len() - 20].to_vec();
        let mut reader = Inflated::start(io::Cursor::new(cut)).expect("thread");
        let mut out = Vec::new();
        let e = reader.read_to_end(&mut out).expect_err("cut");
        assert_eq!(e.kind(), io::ErrorKind::UnexpectedEof);
        assert!(
            out.len() > BLOCK && out.iter().all(|&b| b == b'x'),
            "{} bytes before the error",
            out.len()
        );
        assert_eq!(reader.read(&mut [0; 16]).expect("ended"), 0, "nothing after the error");
    }
}
