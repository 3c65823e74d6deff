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

/// One answer of a queryable: the key it answers for, its encoding and its bytes.
#[derive(Debug, Clone)]
pub struct Answer {
    /// The key (it must match the query's key expression).
    pub key: String,
    /// The encoding (a [`crate::wire`] encoding).
    pub encoding: String,
    /// The bytes, shared with whoever keeps them.
    pub bytes: std::sync::Arc<Vec<u8>>,
}

/// Declares a queryable on `key` (wildcards allowed): `f` gets each query's key expression
/// and returns the answers, on Zenoh's thread (it must not block). Read-only by design: a
/// query carries no payload the gateway reads.
pub fn serve<F>(
    session: &zenoh::Session,
    key: String,
    f: F,
) -> Result<zenoh::query::Queryable<()>, SessionError>
where
    F: Fn(&zenoh::key_expr::KeyExpr<'_>) -> Vec<Answer> + Send + Sync + 'static,
{
    session
        .declare_queryable(key.clone())
        .callback(move |q| {
            for a in f(q.key_expr()) {
                let r = q
                    .reply(a.key.clone(), a.bytes.as_slice().to_vec())
                    .encoding(a.encoding.as_str())
                    .wait();
                if let Err(e) = r {
                    tracing::warn!(key = %a.key, "cannot answer a query: {e}");
                }
            }
        })
        .wait()
        .map_err(|source| SessionError::Declare {
            what: "queryable",
            key,
            source,
        })
}

/// An answer a query got: its key, its encoding and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Got {
    /// The key it answers for.
    pub key: String,
    /// Its encoding, as Zenoh writes it.
    pub encoding: String,
    /// Its bytes.
    pub bytes: Vec<u8>,
}

/// Asks `key` (wildcards allowed) and waits for the answers, at most `timeout`: every answer
/// that came (none: nobody answers that key, or not yet). Error replies are logged and left
/// out.
pub fn fetch(
    session: &zenoh::Session,
    key: String,
    timeout: std::time::Duration,
) -> Result<Vec<Got>, SessionError> {
    let replies = session
        .get(key.clone())
        .timeout(timeout)
        .wait()
        .map_err(|source| SessionError::Declare {
            what: "query",
            key: key.clone(),
            source,
        })?;
    let mut got = Vec::new();
    while let Ok(r) = replies.recv() {
        match r.result() {
            Ok(s) => got.push(Got {
                key: s.key_expr().as_str().to_owned(),
                encoding: s.encoding().to_string(),
                bytes: s.payload().to_bytes().into_owned(),
            }),
            Err(e) => {
                let why = e.payload().to_bytes();
                tracing::warn!(%key, "the query was answered with an error: {}", String::from_utf8_lossy(&why));
            }
        }
    }
    Ok(got)
}

/// [`fetch`] of one `T` (a [`Wire`] message): the first answer that decodes, or why none did
/// (`None`: nobody answered).
pub fn fetch_one<T: Wire>(
    session: &zenoh::Session,
    key: String,
    timeout: std::time::Duration,
) -> Result<Option<Result<T, DecodeError>>, SessionError> {
    let got = fetch(session, key, timeout)?;
    let mut first_err = None;
    for g in got {
        match decode::<T>(&g.bytes, &g.encoding) {
            Ok(m) => return Ok(Some(Ok(m))),
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    Ok(first_err.map(Err))
}
