//! A byte stream that counts what it receives. The Modbus driver wraps its link in it to tell a
//! silent station from one that answered with bytes no valid frame could be made of: the RTU
//! decoder drops bytes with a bad CRC and keeps waiting, so a corrupt response otherwise looks
//! like a timeout.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// `inner`, with every byte read added to a shared counter.
#[derive(Debug)]
pub struct RxCounter<S> {
    inner: S,
    received: Arc<AtomicU64>,
}

impl<S> RxCounter<S> {
    /// Wraps `inner`; `received` counts the bytes read through it.
    pub fn new(inner: S, received: Arc<AtomicU64>) -> Self {
        RxCounter { inner, received }
    }

    /// The stream inside.
    pub fn get_ref(&self) -> &S {
        &self.inner
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for RxCounter<S> {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.inner).poll_read(cx, buf);
        let read = buf.filled().len() - before;
        self.received.fetch_add(read as u64, Ordering::Relaxed);
        polled
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for RxCounter<S> {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[test]
    fn counts_what_it_reads_not_what_it_writes() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        runtime.block_on(async {
            let (a, mut b) = tokio::io::duplex(64);
            let received = Arc::new(AtomicU64::new(0));
            let mut counted = RxCounter::new(a, Arc::clone(&received));
            counted.write_all(b"request").await.expect("write");
            b.write_all(b"reply!").await.expect("write");
            let mut got = [0u8; 6];
            counted.read_exact(&mut got).await.expect("read");
            assert_eq!(&got, b"reply!");
            assert_eq!(received.load(Ordering::Relaxed), 6);
        });
    }
}
