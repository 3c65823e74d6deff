//! A TCP delay line in a network namespace: a relay on the namespace's loopback to a target,
//! holding every chunk, both ways, a set time before passing it on. It stands in for `tc
//! netem` delay where the kernel has none (`scl bench latency --remote`, the whole-graph
//! network tests).

use std::io::{Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

/// Why a relay could not start.
#[derive(Debug, thiserror::Error)]
#[error("the delay relay in namespace {netns}: {source}")]
pub struct RelayError {
    /// The namespace.
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
    stop: Arc<AtomicBool>,
}

impl Relay {
    /// Starts a relay in network namespace `netns` to `target` (`ip:port`) holding every
    /// chunk `delay`.
    pub fn start(netns: &str, target: String, delay: Duration) -> Result<Self, RelayError> {
        let err = |source| RelayError {
            netns: netns.to_owned(),
            source,
        };
        let (port_tx, port_rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let delay_us = Arc::new(AtomicU64::new(0));
        let (st, d) = (Arc::clone(&stop), Arc::clone(&delay_us));
        let path = format!("/var/run/netns/{netns}");
        std::thread::Builder::new()
            .name("bench-relay".into())
            .spawn(move || {
                // This thread (and those it starts) live in the operator's namespace.
                let listener = std::fs::File::open(&path)
                    .and_then(|f| {
                        nix::sched::setns(f, nix::sched::CloneFlags::CLONE_NEWNET)
                            .map_err(std::io::Error::from)
                    })
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
                                    pipe(f, t, &d, &st);
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
/// then), a writer sends it then.
fn pipe(mut from: TcpStream, mut to: TcpStream, delay_us: &Arc<AtomicU64>, stop: &Arc<AtomicBool>) {
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
    let st = Arc::clone(stop);
    std::thread::spawn(move || {
        while let Ok((due, bytes)) = rx.recv() {
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
            if st.load(Ordering::Relaxed) || to.write_all(&bytes).is_err() {
                break;
            }
        }
        let _ = to.shutdown(std::net::Shutdown::Both);
    });
}
