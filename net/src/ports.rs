//! Typed publishers and subscribers over a Zenoh session: every message with its encoding
//! ([`crate::wire`]), every refusal decoded before anyone reads a field.

use std::marker::PhantomData;

use zenoh::Wait as _;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::sample::SampleKind;

use crate::session::SessionError;
use crate::wire::{DecodeError, Wire, decode, encode, encoding_of};

/// How a publisher's samples travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Urgency {
    /// Control input (joystick, e-stop): real-time priority, not batched, dropped rather than
    /// queued behind a congested link (a late sample is worthless: the next one replaces it).
    Control,
    /// Observers' data: data priority, batched, dropped under congestion.
    Observe,
}

/// A publisher of `T` on one key.
#[derive(Debug)]
pub struct Out<T> {
    publisher: zenoh::pubsub::Publisher<'static>,
    _t: PhantomData<fn(T)>,
}

impl<T: Wire> Out<T> {
    /// Publishes `m` (never blocks: congestion drops it).
    pub fn put(&self, m: &T) -> Result<(), zenoh::Error> {
        self.publisher.put(encode(m).to_vec()).wait()
    }

    /// The key.
    pub fn key(&self) -> &str {
        self.publisher.key_expr().as_str()
    }
}

/// Declares a publisher of `T` on `key`.
pub fn publisher<T: Wire>(
    session: &zenoh::Session,
    key: String,
    urgency: Urgency,
) -> Result<Out<T>, SessionError> {
    let (priority, express) = match urgency {
        Urgency::Control => (Priority::RealTime, true),
        Urgency::Observe => (Priority::Data, false),
    };
    let publisher = session
        .declare_publisher(key.clone())
        .encoding(encoding_of::<T>())
        .congestion_control(CongestionControl::Drop)
        .priority(priority)
        .express(express)
        .wait()
        .map_err(|source| SessionError::Declare {
            what: "publisher",
            key,
            source,
        })?;
    Ok(Out {
        publisher,
        _t: PhantomData,
    })
}

/// Subscribes to `T` on `key` (a key expression, wildcards allowed); `f` gets each sample's
/// key and the decoded message or why it was refused, on Zenoh's thread: it must not block.
pub fn subscribe<T, F>(
    session: &zenoh::Session,
    key: String,
    f: F,
) -> Result<zenoh::pubsub::Subscriber<()>, SessionError>
where
    T: Wire,
    F: Fn(&str, Result<T, DecodeError>) + Send + Sync + 'static,
{
    session
        .declare_subscriber(key.clone())
        .callback(move |s| {
            let encoding = s.encoding().to_string();
            let bytes = s.payload().to_bytes();
            f(s.key_expr().as_str(), decode::<T>(&bytes, &encoding));
        })
        .wait()
        .map_err(|source| SessionError::Declare {
            what: "subscriber",
            key,
            source,
        })
}

/// Watches the liveliness tokens below `key`: `f` gets each token's key and whether it
/// appeared (`true`) or went, the present ones first.
pub fn watch_liveliness<F>(
    session: &zenoh::Session,
    key: String,
    f: F,
) -> Result<zenoh::pubsub::Subscriber<()>, SessionError>
where
    F: Fn(&str, bool) + Send + Sync + 'static,
{
    session
        .liveliness()
        .declare_subscriber(key.clone())
        .history(true)
        .callback(move |s| f(s.key_expr().as_str(), s.kind() == SampleKind::Put))
        .wait()
        .map_err(|source| SessionError::Declare {
            what: "liveliness subscriber",
            key,
            source,
        })
}

/// Declares a liveliness token on `key` (it lives as long as the value and the session).
pub fn token(
    session: &zenoh::Session,
    key: String,
) -> Result<zenoh::liveliness::LivelinessToken, SessionError> {
    session
        .liveliness()
        .declare_token(key.clone())
        .wait()
        .map_err(|source| SessionError::Declare {
            what: "liveliness token",
            key,
            source,
        })
}
