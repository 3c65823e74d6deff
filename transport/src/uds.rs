//! The comparison transport: the same fixed-size messages over Unix-domain datagram sockets,
//! the kernel path that socket-based middleware takes. It exists so `scl bench latency` can
//! measure the graph on both transports in one run; the graph's guarantees that rest on
//! iceoryx2 (one `SafeCommand` publisher, history for late joiners) do not hold on it.
//!
//! Each subscriber binds a socket file in the topic's directory
//! (`/tmp/scl-uds/<prefix>/<topic>/`); a publisher sends every message to every socket in that
//! directory, without blocking (a full receiver drops the message, like iceoryx2's safe
//! overflow). Messages are sent as their bytes, so the transport takes only a [`Datagram`]: a
//! type whose `zerocopy` derives prove it has no padding (every byte sent is initialised) and
//! that any bytes of its size are a valid value (nothing read from a socket is undefined).

use std::io::ErrorKind;
use std::marker::PhantomData;
use std::os::unix::io::AsRawFd;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use zerocopy::{FromBytes, Immutable, IntoBytes};

/// Root of every graph's socket directories.
pub const ROOT: &str = "/tmp/scl-uds";

/// How often a publisher re-reads the topic directory for new subscribers.
const RESCAN: Duration = Duration::from_millis(100);

/// Errors of the socket transport.
#[derive(Debug, thiserror::Error)]
pub enum UdsError {
    /// A socket or directory operation failed.
    #[error("{op} {path}: {source}")]
    Io {
        /// What was done.
        op: &'static str,
        /// On what.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A datagram of the wrong size arrived (another message type on the topic).
    #[error("{path}: a datagram of {found} bytes arrived, the topic carries {expected}")]
    Size {
        /// The socket.
        path: PathBuf,
        /// Received size.
        found: usize,
        /// Message size.
        expected: usize,
    },
}

fn io(op: &'static str, path: &Path, source: std::io::Error) -> UdsError {
    UdsError::Io {
        op,
        path: path.to_owned(),
        source,
    }
}

/// The directory of `topic` in graph `prefix`.
pub fn topic_dir(prefix: &str, topic: &str) -> PathBuf {
    Path::new(ROOT).join(prefix).join(topic)
}

/// Removes graph `prefix`'s socket directories (the last process out calls it).
pub fn remove_graph(prefix: &str) {
    let _ = std::fs::remove_dir_all(Path::new(ROOT).join(prefix));
}

/// What the socket transport carries: a `Copy` type whose bytes are all initialised (no
/// padding: [`IntoBytes`]), any bytes of whose size are a valid value ([`FromBytes`]: no
/// `bool`, `char`, enum or reference inside) and without interior mutability
/// ([`Immutable`]). Implemented for every such type; a message gets it by deriving the three
/// `zerocopy` traits on its `#[repr(C)]` definition, which fails to compile if the layout has
/// padding.
pub trait Datagram: IntoBytes + FromBytes + Immutable + Copy {}

impl<T: IntoBytes + FromBytes + Immutable + Copy> Datagram for T {}

/// A publisher of `T` on one topic.
///
/// ```no_run
/// use transport::uds::{UdsPublisher, topic_dir};
///
/// #[derive(Clone, Copy, zerocopy::IntoBytes, zerocopy::FromBytes, zerocopy::Immutable)]
/// #[repr(C)]
/// struct Sample {
///     seq: u32,
///     value: f32,
/// }
///
/// let mut p = UdsPublisher::<Sample>::new(&topic_dir("doc", "samples")).unwrap();
/// p.send(&Sample { seq: 1, value: 0.5 });
/// ```
///
/// A type with padding has uninitialised bytes, which must not be sent: it cannot derive
/// `IntoBytes`, so it is not a [`Datagram`]:
///
/// ```compile_fail
/// use transport::uds::{UdsPublisher, topic_dir};
///
/// #[derive(Clone, Copy, zerocopy::IntoBytes, zerocopy::FromBytes, zerocopy::Immutable)]
/// #[repr(C)]
/// struct Sample {
///     seq: u8, // three bytes of padding follow
///     value: f32,
/// }
///
/// let mut p = UdsPublisher::<Sample>::new(&topic_dir("doc", "samples")).unwrap();
/// p.send(&Sample { seq: 1, value: 0.5 });
/// ```
///
/// and being `Copy` (the bound before `Datagram`) is not enough:
///
/// ```compile_fail
/// use transport::uds::{UdsPublisher, topic_dir};
///
/// #[derive(Clone, Copy)]
/// #[repr(C)]
/// struct Sample {
///     seq: u8,
///     value: f32,
/// }
///
/// let mut p = UdsPublisher::<Sample>::new(&topic_dir("doc", "samples")).unwrap();
/// p.send(&Sample { seq: 1, value: 0.5 });
/// ```
#[derive(Debug)]
pub struct UdsPublisher<T> {
    dir: PathBuf,
    socket: UnixDatagram,
    peers: Vec<PathBuf>,
    scanned: Option<Instant>,
    /// Messages a full or vanished receiver did not take.
    pub dropped: u64,
    _t: PhantomData<T>,
}

impl<T: Datagram> UdsPublisher<T> {
    /// A publisher on the topic directory `dir`.
    pub fn new(dir: &Path) -> Result<Self, UdsError> {
        std::fs::create_dir_all(dir).map_err(|e| io("create", dir, e))?;
        let socket = UnixDatagram::unbound().map_err(|e| io("socket for", dir, e))?;
        socket
            .set_nonblocking(true)
            .map_err(|e| io("set non-blocking", dir, e))?;
        Ok(Self {
            dir: dir.to_owned(),
            socket,
            peers: Vec::new(),
            scanned: None,
            dropped: 0,
            _t: PhantomData,
        })
    }

    fn rescan(&mut self) {
        self.peers.clear();
        if let Ok(rd) = std::fs::read_dir(&self.dir) {
            self.peers.extend(
                rd.flatten()
                    .map(|e| e.path())
                    .filter(|p| p.extension().is_some_and(|e| e == "sock")),
            );
        }
        self.scanned = Some(Instant::now());
    }

    /// Sends `msg` to every subscriber; returns how many took it.
    pub fn send(&mut self, msg: &T) -> usize {
        if self.scanned.is_none_or(|t| t.elapsed() > RESCAN) {
            self.rescan();
        }
        let bytes = msg.as_bytes();
        let mut delivered = 0;
        let mut stale = false;
        for p in &self.peers {
            match self.socket.send_to(bytes, p) {
                Ok(_) => delivered += 1,
                Err(e) if e.kind() == ErrorKind::WouldBlock => self.dropped += 1,
                Err(_) => {
                    // The subscriber is gone (refused, removed): forget it.
                    self.dropped += 1;
                    stale = true;
                }
            }
        }
        if stale {
            self.rescan();
        }
        delivered
    }
}

static NEXT: AtomicU32 = AtomicU32::new(0);

/// A subscriber of `T` on one topic: a bound socket, removed when dropped.
///
/// ```no_run
/// use transport::uds::{UdsSubscriber, topic_dir};
///
/// let s = UdsSubscriber::<ipc_types::RobotState>::new(&topic_dir("doc", "robot_state")).unwrap();
/// s.drain(|state| println!("tick {}", state.tick)).unwrap();
/// ```
///
/// Only types for which every bit pattern is a value can be received, since the bytes come
/// from another process: not a `bool` (only 0 and 1 are valid),
///
/// ```compile_fail
/// use transport::uds::{UdsSubscriber, topic_dir};
///
/// let s = UdsSubscriber::<bool>::new(&topic_dir("doc", "flags")).unwrap();
/// s.drain(|flag| println!("{flag}")).unwrap();
/// ```
///
/// nor a reference (an address from another process):
///
/// ```compile_fail
/// use transport::uds::{UdsSubscriber, topic_dir};
///
/// let s = UdsSubscriber::<&'static u64>::new(&topic_dir("doc", "refs")).unwrap();
/// s.drain(|r| println!("{r}")).unwrap();
/// ```
///
/// and neither can be sent:
///
/// ```compile_fail
/// use transport::uds::{UdsPublisher, topic_dir};
///
/// let mut p = UdsPublisher::<bool>::new(&topic_dir("doc", "flags")).unwrap();
/// p.send(&true);
/// ```
#[derive(Debug)]
pub struct UdsSubscriber<T> {
    path: PathBuf,
    socket: UnixDatagram,
    _t: PhantomData<T>,
}

impl<T: Datagram> UdsSubscriber<T> {
    /// A subscriber on the topic directory `dir`.
    pub fn new(dir: &Path) -> Result<Self, UdsError> {
        std::fs::create_dir_all(dir).map_err(|e| io("create", dir, e))?;
        let n = NEXT.fetch_add(1, Ordering::SeqCst);
        let path = dir.join(format!("{}-{n}.sock", std::process::id()));
        let _ = std::fs::remove_file(&path);
        let socket = UnixDatagram::bind(&path).map_err(|e| io("bind", &path, e))?;
        socket
            .set_nonblocking(true)
            .map_err(|e| io("set non-blocking", &path, e))?;
        Ok(Self {
            path,
            socket,
            _t: PhantomData,
        })
    }

    /// Calls `f` with every received message, oldest first.
    pub fn drain(&self, mut f: impl FnMut(&T)) -> Result<usize, UdsError> {
        let mut buf = [0u8; 1024];
        let mut n = 0;
        loop {
            match self.socket.recv(&mut buf) {
                Ok(len) => {
                    // A copy out of the byte buffer (unaligned); refused unless exactly
                    // `size_of::<T>()` bytes arrived.
                    let msg = T::read_from_bytes(&buf[..len]).map_err(|_| UdsError::Size {
                        path: self.path.clone(),
                        found: len,
                        expected: size_of::<T>(),
                    })?;
                    f(&msg);
                    n += 1;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(n),
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(io("receive on", &self.path, e)),
            }
        }
    }

    /// The socket's file descriptor, for `poll`.
    pub fn raw_fd(&self) -> i32 {
        self.socket.as_raw_fd()
    }
}

impl<T> Drop for UdsSubscriber<T> {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Waits until one of `fds` is readable or `timeout` passes; returns a bit per fd (bit `i`
/// for `fds[i]`, at most 64). A signal ends the wait early with no bit set.
///
/// The timeout keeps its nanoseconds (`ppoll`): `poll` counts whole milliseconds, so a wait
/// for the last 0.6 ms of a 1 kHz tick would become a busy loop that starves the processes
/// the caller waits for on its CPU.
pub fn poll_readable(fds: &[i32], timeout: Duration) -> u64 {
    use nix::poll::{PollFd, PollFlags, ppoll};
    use nix::sys::time::TimeSpec;
    use std::os::fd::BorrowedFd;
    let mut pfds: Vec<PollFd<'_>> = fds
        .iter()
        .map(|fd| {
            // SAFETY: the callers' descriptors (their subscribers' and wakers') stay open for
            // the duration of this call, which is as long as the borrow lives.
            let fd = unsafe { BorrowedFd::borrow_raw(*fd) };
            PollFd::new(fd, PollFlags::POLLIN)
        })
        .collect();
    match ppoll(&mut pfds, Some(TimeSpec::from_duration(timeout)), None) {
        Ok(n) if n > 0 => {}
        // Nothing ready, or a signal (EINTR) ended the wait.
        _ => return 0,
    }
    pfds.iter()
        .take(64)
        .enumerate()
        .filter(|(_, p)| p.revents().is_some_and(|r| r.contains(PollFlags::POLLIN)))
        .fold(0, |bits, (i, _)| bits | (1 << i))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publish_and_receive_between_sockets() {
        let dir = topic_dir(&format!("ut{}", std::process::id()), "t");
        let a = UdsSubscriber::<[u64; 3]>::new(&dir).unwrap();
        let b = UdsSubscriber::<[u64; 3]>::new(&dir).unwrap();
        let mut p = UdsPublisher::<[u64; 3]>::new(&dir).unwrap();
        assert_eq!(p.send(&[1, 2, 3]), 2);
        assert_eq!(p.send(&[4, 5, 6]), 2);
        assert_ne!(
            poll_readable(&[a.raw_fd(), b.raw_fd()], Duration::from_millis(100)),
            0
        );
        let mut got = Vec::new();
        a.drain(|m| got.push(*m)).unwrap();
        assert_eq!(got, vec![[1, 2, 3], [4, 5, 6]]);
        assert_eq!(b.drain(|_| {}).unwrap(), 2);
        assert_eq!(poll_readable(&[a.raw_fd()], Duration::from_millis(1)), 0);
        // A sub-millisecond wait sleeps for it (not a busy loop of zero-timeout polls).
        let t0 = Instant::now();
        assert_eq!(poll_readable(&[a.raw_fd()], Duration::from_micros(600)), 0);
        assert!(t0.elapsed() >= Duration::from_micros(600));
        // A subscriber that leaves is forgotten.
        drop(b);
        std::thread::sleep(RESCAN + Duration::from_millis(10));
        assert_eq!(p.send(&[7, 8, 9]), 1);
        drop(a);
        remove_graph(&format!("ut{}", std::process::id()));
        assert!(!dir.exists());
    }

    #[test]
    fn a_message_arrives_as_it_was_sent() {
        let dir = topic_dir(&format!("uw{}", std::process::id()), "status");
        let s = UdsSubscriber::<ipc_types::NodeStatus>::new(&dir).unwrap();
        let mut p = UdsPublisher::<ipc_types::NodeStatus>::new(&dir).unwrap();
        let mut sent =
            ipc_types::NodeStatus::new(ipc_types::NodeRole::Safety, ipc_types::phase::RUNNING, 7);
        sent.rule_counts[3] = 42;
        sent.joint_travel_rad = 1.5;
        assert_eq!(p.send(&sent), 1);
        std::thread::sleep(Duration::from_millis(5));
        let mut got = Vec::new();
        s.drain(|m| got.push(*m)).unwrap();
        assert_eq!(got, vec![sent]);
        drop(s);
        remove_graph(&format!("uw{}", std::process::id()));
    }

    #[test]
    fn a_wrong_size_is_an_error() {
        let dir = topic_dir(&format!("uv{}", std::process::id()), "t");
        let s = UdsSubscriber::<[u64; 2]>::new(&dir).unwrap();
        let mut p = UdsPublisher::<[u8; 3]>::new(&dir).unwrap();
        p.send(&[1, 2, 3]);
        std::thread::sleep(Duration::from_millis(5));
        assert!(matches!(
            s.drain(|_| {}),
            Err(UdsError::Size { found: 3, .. })
        ));
        drop(s);
        remove_graph(&format!("uv{}", std::process::id()));
    }
}
