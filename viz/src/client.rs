//! A minimal Foxglove WebSocket client (protocol `foxglove.sdk.v1`, as the server speaks
//! it): connect, collect the advertised channels, subscribe, read message frames. For the
//! whole-graph tests and `scl bench latency --live`; Foxglove itself is the real client.

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket};

/// The subprotocol the client offers.
pub const SUBPROTOCOL: &str = "foxglove.sdk.v1";

/// Why the client failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// Connecting or the WebSocket handshake failed.
    #[error("cannot connect to {addr}: {reason}")]
    Connect {
        /// The address.
        addr: String,
        /// Why.
        reason: String,
    },
    /// The connection failed later.
    #[error("the Foxglove connection failed: {0}")]
    Io(String),
}

/// One channel the server advertised.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Advertised {
    /// Channel id.
    pub id: u64,
    /// Topic.
    pub topic: String,
    /// Message encoding.
    pub encoding: String,
    /// Schema name.
    pub schema_name: String,
}

/// One message frame: the subscription it belongs to, its log time and its payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Subscription id (the client's; [`Client::subscribe`] uses the channel id).
    pub subscription: u32,
    /// Log time (ns).
    pub t_ns: u64,
    /// The message.
    pub data: Vec<u8>,
}

/// A connected client.
pub struct Client {
    ws: WebSocket<TcpStream>,
    /// Channels advertised so far, by id.
    pub channels: BTreeMap<u64, Advertised>,
}

impl Client {
    /// Connects to `ws://addr` (the TCP connection given up after `timeout` too: an
    /// unreachable host does not hold the caller for the kernel's minutes) and waits up to
    /// `timeout` for the server's advertisements.
    pub fn connect(addr: &str, timeout: Duration) -> Result<Self, ClientError> {
        use std::net::ToSocketAddrs as _;
        let cerr = |reason: String| ClientError::Connect {
            addr: addr.to_owned(),
            reason,
        };
        let sock = addr
            .to_socket_addrs()
            .map_err(|e| cerr(e.to_string()))?
            .next()
            .ok_or_else(|| cerr("the address resolves to nothing".into()))?;
        let stream = TcpStream::connect_timeout(&sock, timeout.max(Duration::from_millis(100)))
            .map_err(|e| cerr(e.to_string()))?;
        stream
            .set_read_timeout(Some(Duration::from_millis(100)))
            .map_err(|e| cerr(e.to_string()))?;
        let mut req = format!("ws://{addr}/")
            .into_client_request()
            .map_err(|e| cerr(e.to_string()))?;
        req.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            tungstenite::http::HeaderValue::from_static(SUBPROTOCOL),
        );
        let (ws, _) = tungstenite::client(req, stream).map_err(|e| cerr(e.to_string()))?;
        let mut c = Self {
            ws,
            channels: BTreeMap::new(),
        };
        let t0 = Instant::now();
        while c.channels.is_empty() && t0.elapsed() < timeout {
            c.next_frame()?;
        }
        Ok(c)
    }

    /// The id of the channel on `topic`.
    pub fn channel(&self, topic: &str) -> Option<u64> {
        self.channels
            .values()
            .find(|c| c.topic == topic)
            .map(|c| c.id)
    }

    /// Subscribes to channel `id` with subscription id `id`.
    pub fn subscribe(&mut self, ids: &[u64]) -> Result<(), ClientError> {
        let subs: Vec<serde_json::Value> = ids
            .iter()
            .map(|id| serde_json::json!({ "id": id, "channelId": id }))
            .collect();
        let text = serde_json::json!({ "op": "subscribe", "subscriptions": subs }).to_string();
        self.ws
            .send(Message::text(text))
            .map_err(|e| ClientError::Io(e.to_string()))
    }

    /// Reads until a message frame arrives or 100 ms pass; advertisements update
    /// [`Client::channels`] on the way.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, ClientError> {
        match self.ws.read() {
            Ok(Message::Binary(b)) if b.first() == Some(&1) && b.len() >= 13 => {
                let mut sub = [0u8; 4];
                sub.copy_from_slice(&b[1..5]);
                let mut t = [0u8; 8];
                t.copy_from_slice(&b[5..13]);
                Ok(Some(Frame {
                    subscription: u32::from_le_bytes(sub),
                    t_ns: u64::from_le_bytes(t),
                    data: b[13..].to_vec(),
                }))
            }
            Ok(Message::Text(t)) => {
                let v: serde_json::Value = serde_json::from_str(t.as_str()).unwrap_or_default();
                if v["op"] == "advertise"
                    && let Some(chs) = v["channels"].as_array()
                {
                    for ch in chs {
                        if let Some(id) = ch["id"].as_u64() {
                            self.channels.insert(
                                id,
                                Advertised {
                                    id,
                                    topic: ch["topic"].as_str().unwrap_or_default().to_owned(),
                                    encoding: ch["encoding"]
                                        .as_str()
                                        .unwrap_or_default()
                                        .to_owned(),
                                    schema_name: ch["schemaName"]
                                        .as_str()
                                        .unwrap_or_default()
                                        .to_owned(),
                                },
                            );
                        }
                    }
                }
                Ok(None)
            }
            Ok(_) => Ok(None),
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                Ok(None)
            }
            Err(e) => Err(ClientError::Io(e.to_string())),
        }
    }

    /// Closes the connection politely.
    pub fn close(mut self) {
        let _ = self.ws.close(None);
        let _ = self.ws.flush();
    }
}
