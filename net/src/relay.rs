//! A TCP delay line in a network namespace: a relay on the namespace's loopback to a target,
//! holding every chunk, both ways, a set time before passing it on. It stands in for `tc
//! netem` delay where the kernel has none (`scl bench latency --remote`, the whole-graph
//! network tests), and for a pulled cable ([`Relay::cut`], `scl drill`'s link cut, which runs
//! in the machine's own namespace without root).

use std::io::{Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

/// Why a relay could not start.
#[derive(Debug, thiserror::Error)]
#[error("the delay relay in namespace {netns}: {source}")]
pub struct RelayError {
    /// The namespace (`-`: the process's own).
    pub netns: String,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

/// A TCP relay in the operator's namespace, listening on its loopback and connecting to the
/// gateway: every chunk, both ways, is held the delay ([`Relay::set_delay`]) before it is
/// passed on, in order. Stops when dropped. `scl bench latency --remote` and the
/// whole-graph network tests add delay with it (the machines' kernel has no netem).
pub struct Relay {
    port: u16,
    delay_us: Arc<AtomicU64>,
    cut: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
}

impl Relay {
    /// Starts a relay in network namespace `netns` to `target` (`ip:port`) holding every
    /// chunk `delay`.
    pub fn start(netns: &str, target: String, delay: Duration) -> Result<Self, RelayError> {
        Self::start_in(Some(netns), target, delay)
    }

    /// Starts a relay in this process's own network namespace (no root needed) to `target`
    /// (`ip:port`), passing every chunk at once until [`Relay::cut`].
    pub fn start_here(target: String) -> Result<Self, RelayError> {
        Self::start_in(None, target, Duration::ZERO)
    }

    fn start_in(netns: Option<&str>, target: String, delay: Duration) -> Result<Self, RelayError> {
        let err = |source| RelayError {
            netns: netns.unwrap_or("-").to_owned(),
            source,
        };
        let (port_tx, port_rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let cut = Arc::new(AtomicBool::new(false));
        let delay_us = Arc::new(AtomicU64::new(0));
        let (st, d, c) = (Arc::clone(&stop), Arc::clone(&delay_us), Arc::clone(&cut));
        let path = netns.map(|n| format!("/var/run/netns/{n}"));
        std::thread::Builder::new()
            .name("relay".into())
            .spawn(move || {
                // This thread (and those it starts) live in the operator's namespace.
                let entered = match &path {
                    Some(path) => std::fs::File::open(path).and_then(|f| {
                        nix::sched::setns(f, nix::sched::CloneFlags::CLONE_NEWNET)
                            .map_err(std::io::Error::from)
                    }),
                    None => Ok(()),
                };
                let listener = entered
                    .and_then(|()| TcpListener::bind("127.0.0.1:0"))
                    .and_then(|l| l.set_nonblocking(true).map(|()| l))
                    .and_then(|l| l.local_addr().map(|a| (l, a.port())));
                let l = match listener {
                    Ok((l, port)) => {
                        let _ = port_tx.send(Ok(port));
                        l
                    }
                    Err(e) => {
                        let _ = port_tx.send(Err(e));
                        return;
                    }
                };
                while !st.load(Ordering::Relaxed) {
                    match l.accept() {
                        Ok((a, _)) => {
                            // The gateway gone: the operator's retry fails.
                            let Ok(b) = TcpStream::connect(&target) else {
                                continue;
                            };
                            // As Zenoh's own sockets: no Nagle (it would hold small samples
                            // for the peer's delayed acknowledgement).
                            let _ = a.set_nodelay(true).and(b.set_nodelay(true));
                            let _ = a.set_nonblocking(false);
                            for (from, to) in [(&a, &b), (&b, &a)] {
                                if let (Ok(f), Ok(t)) = (from.try_clone(), to.try_clone()) {
                                    pipe(f, t, &d, &c, &st);
                                }
                            }
                        }
                        Err(_) => std::thread::sleep(Duration::from_millis(5)),
                    }
                }
            })
            .map_err(err)?;
        let port = port_rx
            .recv_timeout(Duration::from_secs(5))
            .map_err(|e| err(std::io::Error::other(e.to_string())))?
            .map_err(err)?;
        let relay = Self {
            port,
            delay_us,
            cut,
            stop,
        };
        relay.set_delay(delay);
        Ok(relay)
    }

    /// Holds every chunk from now on `d` (each way).
    pub fn set_delay(&self, d: Duration) {
        self.delay_us.store(
            u64::try_from(d.as_micros()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
    }

    /// Cuts the link from now on, as a pulled cable does: nothing more passes either way, and
    /// nothing closes (the connections stay open, silent, until the relay is dropped); a
    /// connection made after the cut is as silent.
    pub fn cut(&self) {
        self.cut.store(true, Ordering::Relaxed);
    }

    /// The Zenoh endpoint the operator connects to (in the relay's namespace).
    pub fn endpoint(&self) -> String {
        format!("tcp/127.0.0.1:{}", self.port)
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// One direction of the relay: a reader stamps each chunk with when it is due (the delay
/// then), a writer sends it then. After a cut the writer drops every chunk due and closes
/// nothing until the relay stops.
fn pipe(
    mut from: TcpStream,
    mut to: TcpStream,
    delay_us: &Arc<AtomicU64>,
    cut: &Arc<AtomicBool>,
    stop: &Arc<AtomicBool>,
) {
    let (tx, rx) = mpsc::channel::<(Instant, Vec<u8>)>();
    let d = Arc::clone(delay_us);
    std::thread::spawn(move || {
        let mut buf = [0u8; 65536];
        while let Ok(n) = from.read(&mut buf) {
            let due = Instant::now() + Duration::from_micros(d.load(Ordering::Relaxed));
            if n == 0 || tx.send((due, buf[..n].to_vec())).is_err() {
                break;
            }
        }
    });
    let (st, c) = (Arc::clone(stop), Arc::clone(cut));
    std::thread::spawn(move || {
        loop {
            if st.load(Ordering::Relaxed) {
                break;
            }
            // Woken at least every 50 ms to see a stop; a peer that closed while the link was
            // up closes this side too (its chunks all passed).
            let (due, bytes) = match rx.recv_timeout(Duration::from_millis(50)) {
                Ok(chunk) => chunk,
                Err(mpsc::RecvTimeoutError::Timeout) => continue,
                Err(mpsc::RecvTimeoutError::Disconnected) if c.load(Ordering::Relaxed) => {
                    std::thread::sleep(Duration::from_millis(50));
                    continue;
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            };
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
            if c.load(Ordering::Relaxed) {
                continue;
            }
            if st.load(Ordering::Relaxed) || to.write_all(&bytes).is_err() {
                break;
            }
        }
        let _ = to.shutdown(std::net::Shutdown::Both);
    });
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// An echo server on loopback: its address.
    fn echo() -> String {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap().to_string();
        std::thread::spawn(move || {
            for mut c in l.incoming().flatten() {
                std::thread::spawn(move || {
                    let mut buf = [0u8; 1024];
                    while let Ok(n) = c.read(&mut buf) {
                        if n == 0 || c.write_all(&buf[..n]).is_err() {
                            break;
                        }
                    }
                });
            }
        });
        addr
    }

    /// A cut passes nothing more and closes nothing: the client's read times out, it does not
    /// see the end of the stream, as behind a pulled cable.
    #[test]
    fn a_cut_link_is_silent_and_stays_open() {
        let relay = Relay::start_here(echo()).unwrap();
        let port = relay
            .endpoint()
            .rsplit(':')
            .next()
            .unwrap()
            .parse::<u16>()
            .unwrap();
        let mut c = TcpStream::connect(("127.0.0.1", port)).unwrap();
        c.set_read_timeout(Some(Duration::from_millis(300)))
            .unwrap();
        let mut buf = [0u8; 5];
        c.write_all(b"hello").unwrap();
        c.read_exact(&mut buf).unwrap();
        assert_eq!(&buf, b"hello");
        relay.cut();
        c.write_all(b"again").unwrap();
        let e = c.read(&mut buf).unwrap_err();
        assert!(
            matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ),
            "{e}"
        );
        // Dropped, the relay closes the connection: the end of the stream (or a reset), not a
        // read that times out.
        drop(relay);
        c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        match c.read(&mut buf) {
            Ok(0) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {}
            other => panic!("the dropped relay left the connection open: {other:?}"),
        }
    }
}
