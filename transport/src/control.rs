//! The control plane's services: the supervisor's request-response service (`scl swap`), the
//! e-stop topic and the active-mapper switch the supervisor sends to safety, opened on the
//! graph's iceoryx2 node. The messages are [`ipc_types::control`]'s.

use core::time::Duration;

use iceoryx2::port::client::Client;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use ipc_types::control::{
    ControlRequest, ControlResponse, EstopCommand, SUPERVISOR, SafetyControl,
};
use ipc_types::topics;

use crate::graph::{Graph, IoError, Ipc, IpcError, OpenError, TopicPublisher, TopicSubscriber};

type ControlFactory = iceoryx2::service::port_factory::request_response::PortFactory<
    Ipc,
    ControlRequest,
    (),
    ControlResponse,
    (),
>;

/// The supervisor's end of the control service.
pub type ControlServer = Server<Ipc, ControlRequest, (), ControlResponse, ()>;
/// A client's end of the control service.
pub type ControlClient = Client<Ipc, ControlRequest, (), ControlResponse, ()>;
/// A request the server holds until it answers it (`send_copy` the response).
pub type ActiveControlRequest =
    iceoryx2::active_request::ActiveRequest<Ipc, ControlRequest, (), ControlResponse, ()>;
/// A publisher of e-stop commands.
pub type EstopPublisher = TopicPublisher<EstopCommand>;
/// A subscriber of e-stop commands (safety, the supervisor), drained like any other topic.
pub type EstopSubscriber = TopicSubscriber<EstopCommand>;
/// The supervisor's publisher of active-mapper switches.
pub type SafetyControlPublisher = TopicPublisher<SafetyControl>;
/// Safety's subscriber of active-mapper switches.
pub type SafetyControlSubscriber = TopicSubscriber<SafetyControl>;

impl Graph {
    /// Publisher of active-mapper switches (the supervisor).
    pub fn safety_control_publisher(&self) -> Result<SafetyControlPublisher, IpcError> {
        self.publisher_of(&topics::SAFETY_CONTROL)
    }

    /// Subscriber of active-mapper switches (safety); receives the newest switch at once.
    pub fn safety_control_subscriber(&self) -> Result<SafetyControlSubscriber, IpcError> {
        self.safety_control_observer()
    }

    /// A read-only observer of the active-mapper switches (recorder, dashboard): the same
    /// topic as [`Graph::safety_control_subscriber`], drained like any other topic.
    pub fn safety_control_observer(&self) -> Result<TopicSubscriber<SafetyControl>, IpcError> {
        self.subscriber_of(&topics::SAFETY_CONTROL, false)
    }

    /// A publisher of e-stop commands. Keep it alive until the command took effect: a sample
    /// of a publisher that is gone is not delivered.
    pub fn estop_publisher(&self) -> Result<EstopPublisher, IpcError> {
        self.publisher_of(&topics::ESTOP)
    }

    /// Subscriber of e-stop commands (safety); receives the newest at once.
    pub fn estop_subscriber(&self) -> Result<EstopSubscriber, IpcError> {
        self.estop_observer()
    }

    /// A read-only observer of e-stop commands (recorder).
    pub fn estop_observer(&self) -> Result<TopicSubscriber<EstopCommand>, IpcError> {
        self.subscriber_of(&topics::ESTOP, false)
    }

    fn control_service(&self) -> Result<(String, ControlFactory), IpcError> {
        let full = self.prefix().service(SUPERVISOR);
        let name = ServiceName::new(&full).map_err(|e| IpcError::Open {
            service: full.clone(),
            source: OpenError::Name(e),
        })?;
        let f = self
            .node()
            .service_builder(&name)
            .request_response::<ControlRequest, ControlResponse>()
            .max_servers(1)
            .max_clients(8)
            .max_active_requests_per_client(1)
            .max_response_buffer_size(2)
            .open_or_create()
            .map_err(|e| IpcError::Open {
                service: full.clone(),
                source: e.into(),
            })?;
        Ok((full, f))
    }

    /// The supervisor's server; there is one per graph.
    pub fn control_server(&self) -> Result<ControlServer, IpcError> {
        let (service, f) = self.control_service()?;
        f.server_builder().create().map_err(|e| IpcError::Port {
            service,
            port: "server",
            source: e.into(),
        })
    }

    /// Sends `req` to the graph's supervisor and waits up to `timeout` for the answer.
    pub fn request(
        &self,
        req: ControlRequest,
        timeout: Duration,
    ) -> Result<ControlResponse, IpcError> {
        let (service, f) = self.control_service()?;
        let io = |op: &'static str, source: IoError| IpcError::Io {
            service: service.clone(),
            op,
            source,
        };
        if f.dynamic_config().number_of_servers() == 0 {
            return Err(io("request", IoError::NoServer));
        }
        let client: ControlClient = f.client_builder().create().map_err(|e| IpcError::Port {
            service: service.clone(),
            port: "client",
            source: e.into(),
        })?;
        let pending = client.send_copy(req).map_err(|e| io("send", e.into()))?;
        let t0 = std::time::Instant::now();
        loop {
            if let Some(r) = pending.receive().map_err(|e| io("receive", e.into()))? {
                return Ok(*r.payload());
            }
            if t0.elapsed() > timeout {
                return Err(io("request", IoError::NoAnswer(timeout)));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}
