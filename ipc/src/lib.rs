//! iceoryx2 services of vlsync: service names, ports with one consistent QoS,
//! and the client API.
//!
//! # Services (one robot per prefix)
//!
//! | name                        | pattern            | payload | who publishes / notifies |
//! |-----------------------------|--------------------|---------|--------------------------|
//! | `<prefix>/cam/signature`    | publish-subscribe  | [`SignatureSample`] | `vlsync-cam` |
//! | `<prefix>/lidar/signature`  | publish-subscribe  | [`SignatureSample`] | `vlsync-lidar` |
//! | `<prefix>/signature/ready`  | event (id 0 cam, 1 lidar) | — | both drivers, after each sample |
//! | `<prefix>/offset`           | publish-subscribe + event | [`OffsetEstimate`] | `vlsyncd` |
//! | `<prefix>/status`           | publish-subscribe + event | [`Status`] | `vlsyncd` |
//!
//! The daemon blocks on ONE listener of `<prefix>/signature/ready`, so it sleeps
//! until a driver publishes (no polling, no WaitSet: the 0.10 WaitSet allocates on
//! every wake-up, a single listener does not).
//!
//! # QoS
//!
//! Services are opened with no requirements and, only when they do not exist yet,
//! created with [`Qos`] (see [`open_or_create_pubsub`]): a driver or client started
//! before the daemon creates exactly what the daemon would, and a daemon started
//! with a larger `services.subscriber_buffer` than the service was created with
//! gets the service's maximum (the clamp is reported by [`SubscriberBuffer`]).
//! Every service allows several publishers and nodes, so a restarted process can
//! attach while the dead one's ports are still being reclaimed; safe overflow is
//! on (a slow subscriber loses the oldest sample, never blocks a publisher), and
//! the lost samples show up as sequence gaps in the daemon's status.
//!
//! A service that already exists may have been created by another program (a C++
//! node with iceoryx2's defaults: history 0, subscriber buffers of 2) or another
//! vlsync version: its settings are checked once opened ([`check_service_settings`]).
//! A history shorter than vlsync's (a late client of an idle daemon would wait
//! forever) and safe overflow off are errors naming the service, the setting, what was
//! found and what vlsync expects; fewer publishers or smaller subscriber buffers are
//! [`QosWarning`]s the caller may report ([`OffsetClient::qos_warnings`],
//! [`StatusClient::qos_warnings`], [`service_warnings`]). A payload type of another
//! name, size or alignment is an error naming both types.
#![deny(unsafe_code)]

pub mod rt;
pub mod sd_notify;
pub mod signals;

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::ReceiveError;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use std::fmt;
use std::time::{Duration, Instant};
use vlsync_common::wire::{OffsetEstimate, SignatureSample, Status, WireError};
use vlsync_common::{Estimate, EstimatorState, Nanos, Stream};

pub use iceoryx2;
pub use signals::{handle_termination_signals, termination_requested, STOP_WITH_PARENT_ENV};
pub use vlsync_common::wire;

/// `open(2)`'s `O_NOFOLLOW` on this target (its value differs between
/// architectures), for `OpenOptionsExt::custom_flags`: the daemon opens its lock
/// file, in a directory of `/tmp`, without following a link planted there.
pub const O_NOFOLLOW: i32 = libc::O_NOFOLLOW;

/// `open(2)`'s `O_NONBLOCK` on this target: the lock file's open returns at once where
/// a FIFO was planted under its name (which is then refused as no regular file).
pub const O_NONBLOCK: i32 = libc::O_NONBLOCK;

/// The iceoryx2 service variant used everywhere (inter-process).
pub type Svc = ipc::Service;
/// A node of [`Svc`].
pub type IpcNode = Node<Svc>;

/// What went wrong, and where.
#[derive(Debug, Clone, PartialEq)]
pub struct IpcError {
    /// What was being done (names the service or port).
    pub context: String,
    /// The underlying error.
    pub message: String,
}

impl IpcError {
    /// Builds an error from a context and any displayable cause.
    pub fn new(context: impl Into<String>, cause: impl fmt::Display) -> Self {
        Self {
            context: context.into(),
            message: cause.to_string(),
        }
    }
}

impl fmt::Display for IpcError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.context, self.message)
    }
}

impl std::error::Error for IpcError {}

/// Event id a driver notifies on `<prefix>/signature/ready`.
pub fn stream_event_id(stream: Stream) -> EventId {
    EventId::new(match stream {
        Stream::Cam => 0,
        Stream::Lidar => 1,
    })
}

/// Index of a stream in per-stream arrays (0 cam, 1 lidar).
pub fn stream_index(stream: Stream) -> usize {
    match stream {
        Stream::Cam => 0,
        Stream::Lidar => 1,
    }
}

/// The service names under one prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// The prefix, as validated.
    pub prefix: String,
}

impl ServiceNames {
    /// Validates the prefix with the same rule as `services.prefix` in the configuration.
    pub fn new(prefix: &str) -> Result<Self, IpcError> {
        let cfg = vlsync_config::ServicesConfig {
            prefix: prefix.to_string(),
            ..Default::default()
        };
        cfg.validate("--prefix")
            .map_err(|e| IpcError::new("service prefix (--prefix)", e.message))?;
        Ok(Self {
            prefix: prefix.to_string(),
        })
    }

    /// `<prefix>/<cam|lidar>/signature`
    pub fn signature(&self, stream: Stream) -> String {
        format!("{}/{}/signature", self.prefix, stream.name())
    }

    /// `<prefix>/signature/ready`: event service the drivers notify.
    pub fn signature_ready(&self) -> String {
        format!("{}/signature/ready", self.prefix)
    }

    /// `<prefix>/offset` (publish-subscribe and event).
    pub fn offset(&self) -> String {
        format!("{}/offset", self.prefix)
    }

    /// `<prefix>/status` (publish-subscribe and event).
    pub fn status(&self) -> String {
        format!("{}/status", self.prefix)
    }
}

/// Service-level quality of service used when a service is created.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Samples a late subscriber receives on connection.
    pub history: usize,
    /// Maximum buffer a subscriber may request.
    pub max_buffer: usize,
    /// Publishers at once (a restarted driver, a test publisher, the dead port not yet reclaimed).
    pub max_publishers: usize,
    /// Subscribers at once.
    pub max_subscribers: usize,
    /// Nodes at once.
    pub max_nodes: usize,
}

impl Qos {
    /// Signature streams: no history (stale samples are useless after a restart).
    pub fn signature(subscriber_buffer: usize) -> Self {
        Self {
            history: 0,
            max_buffer: subscriber_buffer.max(DEFAULT_SIGNATURE_BUFFER),
            max_publishers: 4,
            max_subscribers: 4,
            max_nodes: 16,
        }
    }

    /// Offset and status: the last sample is delivered to late subscribers.
    pub fn latest() -> Self {
        Self {
            history: 1,
            max_buffer: 16,
            max_publishers: 2,
            max_subscribers: 16,
            max_nodes: 32,
        }
    }
}

/// Default `services.subscriber_buffer`, and the minimum signature service buffer.
pub const DEFAULT_SIGNATURE_BUFFER: usize = 256;

/// Creates a node named `name`. iceoryx2 is configured (its defaults, unless an
/// iceoryx2 configuration file says otherwise) to remove the resources of dead
/// nodes whenever a node is created, so a process
/// restarted after a crash cleans up behind its predecessor; [`cleanup_dead_nodes`]
/// does it explicitly and reports the count.
///
/// `handle_signals`: install vlsync's SIGINT/SIGTERM handler
/// ([`handle_termination_signals`]; the process then polls
/// [`termination_requested`]); without it the process's signal handling is left as
/// it was (a client library must not take an application's signals). Either way
/// iceoryx2's own signal handlers are undone ([`signals::tame_iceoryx2_signals`]).
pub fn create_node(name: &str, handle_signals: bool) -> Result<IpcNode, IpcError> {
    build_node(name, handle_signals, true)
}

/// [`create_node`] with signal handling, without iceoryx2's clean-up of dead nodes
/// at creation, for a process that calls [`cleanup_dead_nodes`] next and reports
/// its count (the daemon): done at creation, the explicit clean-up found nothing
/// and a crash's clean-up was never said.
pub fn create_node_cleaning_later(name: &str) -> Result<IpcNode, IpcError> {
    build_node(name, true, false)
}

fn build_node(
    name: &str,
    handle_signals: bool,
    cleanup_on_creation: bool,
) -> Result<IpcNode, IpcError> {
    let node_name = NodeName::new(name)
        .map_err(|e| IpcError::new(format!("node name {name:?}"), format!("{e:?}")))?;
    // iceoryx2 logs at Info by default (e.g. "no config file loaded"); keep its
    // warnings quiet unless IOX2_LOG_LEVEL asks otherwise
    set_log_level_from_env_or(LogLevel::Error);
    // before any shared memory: iceoryx2's own handlers would take thirteen signals
    // and keep only the last one (see `signals`)
    if handle_signals {
        handle_termination_signals();
    } else {
        signals::tame_iceoryx2_signals();
    }
    let mut config = iceoryx2::config::Config::global_config().clone();
    // (an iceoryx2 configuration file's `false` is kept)
    config.global.node.cleanup_dead_nodes_on_creation &= cleanup_on_creation;
    NodeBuilder::new()
        .name(&node_name)
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Svc>()
        .map_err(|e| IpcError::new(format!("create iceoryx2 node {name:?}"), format!("{e:?}")))
}

/// Removes the resources of every dead iceoryx2 node (crashed processes) and
/// returns `(cleaned, failed)`.
pub fn cleanup_dead_nodes(node: &IpcNode) -> (u64, u64) {
    let s = node.try_cleanup_dead_nodes();
    (s.cleanups, s.failed_cleanups)
}

/// Now on `CLOCK_MONOTONIC`, ns (the clock of every `publish_ns` field).
pub fn monotonic_ns() -> Nanos {
    use iceoryx2_bb_posix::clock::{ClockType, Time};
    match Time::now_with_clock(ClockType::Monotonic) {
        Ok(t) => {
            let d = t.as_duration();
            (d.as_secs() as i64)
                .saturating_mul(1_000_000_000)
                .saturating_add(i64::from(d.subsec_nanos()))
        }
        // CLOCK_MONOTONIC cannot fail on Linux; 0 marks "unknown" for latency purposes.
        Err(_) => 0,
    }
}

fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name)
        .map_err(|e| IpcError::new(format!("service name {name:?}"), format!("{e:?}")))
}

const OPEN_ATTEMPTS: u32 = 50;
const OPEN_RETRY: Duration = Duration::from_millis(20);

/// Opens publish-subscribe service `name` for payload `T` without constraints,
/// or creates it with `qos` when it does not exist. Retries transient states
/// (being created or torn down by another process) for up to 1 s. A service it
/// opened is checked against `qos` ([`check_service_settings`]: an error for a
/// history shorter than `qos.history` or safe overflow off; [`service_warnings`] gives
/// the lesser differences), and one with another payload type is an error naming ours
/// and, when iceoryx2 can read it, the existing service's.
pub fn open_or_create_pubsub<T: std::fmt::Debug + ZeroCopySend>(
    node: &IpcNode,
    name: &str,
    qos: Qos,
) -> Result<PubSubFactory<Svc, T, ()>, IpcError> {
    let sn = service_name(name)?;
    let mut last = String::new();
    for _ in 0..OPEN_ATTEMPTS {
        match node.service_builder(&sn).publish_subscribe::<T>().open() {
            Ok(s) => {
                // another process created it, perhaps not a vlsync one
                check_service_settings(name, ServiceSettings::of(&s), qos)?;
                return Ok(s);
            }
            Err(PublishSubscribeOpenError::DoesNotExist) => {
                match node
                    .service_builder(&sn)
                    .publish_subscribe::<T>()
                    .history_size(qos.history)
                    .subscriber_max_buffer_size(qos.max_buffer)
                    .max_publishers(qos.max_publishers)
                    .max_subscribers(qos.max_subscribers)
                    .max_nodes(qos.max_nodes)
                    .enable_safe_overflow(true)
                    .create()
                {
                    Ok(s) => return Ok(s),
                    Err(e) => last = format!("create failed: {e:?}"),
                }
            }
            Err(PublishSubscribeOpenError::IncompatibleTypes) => {
                return Err(IpcError::new(
                    format!("open service {name:?}"),
                    incompatible_types::<T>(node, &sn),
                ))
            }
            Err(e) if open_is_transient(&e) => last = format!("open failed: {e:?}"),
            Err(e) => {
                return Err(IpcError::new(
                    format!("open service {name:?}"),
                    open_refusal(&e),
                ))
            }
        }
        std::thread::sleep(OPEN_RETRY);
    }
    Err(IpcError::new(format!("open service {name:?}"), last))
}

/// Whether an open of a publish-subscribe service that failed with `e` is tried
/// again: a state another process passes through (creating or removing the
/// service), a failure inside iceoryx2, or a signal that interrupted the call (a C
/// application's handler usually lacks `SA_RESTART`, and a Ctrl-C it handles must not
/// fail the open as if the service were wrong; the event services retry every error).
fn open_is_transient(e: &PublishSubscribeOpenError) -> bool {
    matches!(
        e,
        PublishSubscribeOpenError::IsMarkedForDestruction
            | PublishSubscribeOpenError::HangsInCreation
            | PublishSubscribeOpenError::InternalFailure
            | PublishSubscribeOpenError::ServiceInCorruptedState
            | PublishSubscribeOpenError::Interrupt
    )
}

/// Why an open of a publish-subscribe service that failed with `e` is given up (not
/// a transient failure, nor another payload type, which names both types): iceoryx2's
/// error with its likely cause, blaming the payload type or settings only where the
/// error is about them.
fn open_refusal(e: &PublishSubscribeOpenError) -> String {
    use PublishSubscribeOpenError as E;
    let cause = match e {
        E::IncompatibleAttributes
        | E::DoesNotSupportRequestedMinBufferSize
        | E::DoesNotSupportRequestedMinHistorySize
        | E::DoesNotSupportRequestedMinSubscriberBorrowedSamples
        | E::DoesNotSupportRequestedAmountOfPublishers
        | E::DoesNotSupportRequestedAmountOfSubscribers
        | E::DoesNotSupportRequestedAmountOfNodes
        | E::IncompatibleOverflowBehavior
        | E::UnableToAcquireTypeDefinition
        | E::InvalidTypeDefinition => {
            "another process uses it with a different payload type or settings"
        }
        E::IncompatibleMessagingPattern => "the name is taken by a service of another kind",
        E::VersionMismatch => "another process created it with another iceoryx2 version",
        E::InsufficientPermissions => {
            "no permission to open it (created by another user, or iceoryx2's files are not \
             readable and writable by this one)"
        }
        E::ExceedsMaxNumberOfNodes => "as many processes use it as it allows",
        E::UnableToCreateServiceTag => {
            "this process's node could not record its use of the service (iceoryx2's \
             directory full or not writable?)"
        }
        _ => "",
    };
    if cause.is_empty() {
        format!("{e:?}")
    } else {
        format!("{e:?} ({cause})")
    }
}

/// The settings of a publish-subscribe service that vlsync depends on, as its creator
/// set them ([`check_service_settings`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServiceSettings {
    /// Samples a late subscriber receives on connection.
    pub history: usize,
    /// Largest buffer a subscriber may request.
    pub max_buffer: usize,
    /// Publishers at once.
    pub max_publishers: usize,
    /// A full subscriber buffer loses its oldest sample (rather than refuse the newest).
    pub safe_overflow: bool,
}

impl ServiceSettings {
    /// The settings of an open service.
    pub fn of<T: std::fmt::Debug + ZeroCopySend>(factory: &PubSubFactory<Svc, T, ()>) -> Self {
        let c = factory.static_config();
        Self {
            history: c.history_size(),
            max_buffer: c.subscriber_max_buffer_size(),
            max_publishers: c.max_publishers(),
            safe_overflow: c.has_safe_overflow(),
        }
    }
}

/// A setting of an opened service below what vlsync creates it with, where vlsync
/// still works ([`check_service_settings`]); its `Display` is a sentence for a log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum QosWarning {
    /// Fewer publishers allowed: a second live publisher (a restarted process while its
    /// dead predecessor's port is still there, a test publisher) is refused by iceoryx2
    /// when it is created, naming the service.
    FewerPublishers {
        /// The service's name.
        service: String,
        /// What the service allows.
        found: usize,
        /// What vlsync creates it with.
        expected: usize,
    },
    /// Smaller subscriber buffers: a subscriber is granted the service's maximum
    /// ([`SubscriberBuffer`]), and one that falls that many samples behind loses the
    /// oldest (safe overflow keeps the newest).
    SmallerBuffer {
        /// The service's name.
        service: String,
        /// What the service allows.
        found: usize,
        /// What vlsync creates it with.
        expected: usize,
    },
}

impl fmt::Display for QosWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (service, what, found, expected) = match self {
            QosWarning::FewerPublishers {
                service,
                found,
                expected,
            } => (service, "publishers at once", found, expected),
            QosWarning::SmallerBuffer {
                service,
                found,
                expected,
            } => (service, "samples of subscriber buffer", found, expected),
        };
        write!(
            f,
            "service `{service}` allows {found} {what}, vlsync creates it with {expected}: \
             {CREATED_ELSEWHERE}"
        )
    }
}

/// What a check of an opened service's settings says of its creator.
const CREATED_ELSEWHERE: &str = "another program (or a vlsync of another version) created it \
     with other settings; vlsync's are `vlsync_ipc::Qos`, listed for C and C++ in \
     examples/c/vlsync_wire.h";

/// Checks the settings of service `name`, opened (another process created it), against
/// the `qos` vlsync would have created it with. Refused (the error names the service,
/// the setting, what was found and what vlsync expects):
/// * a history shorter than `qos.history` (the latest-value services, [`Qos::latest`]):
///   a late subscriber would not be handed the last estimate or status, and would wait
///   for the next, forever from an idle daemon;
/// * safe overflow off: a subscriber's full buffer would refuse the newest samples
///   instead of losing its oldest (a client would read stale estimates; the daemon
///   would lose new signature samples behind a backlog).
///
/// Returned as warnings, since vlsync works with them: fewer publishers at once
/// ([`QosWarning::FewerPublishers`]) and smaller subscriber buffers
/// ([`QosWarning::SmallerBuffer`]). A longer history or larger limits are no concern.
pub fn check_service_settings(
    name: &str,
    found: ServiceSettings,
    qos: Qos,
) -> Result<Vec<QosWarning>, IpcError> {
    let refuse = |what: String| Err(IpcError::new(format!("open service {name:?}"), what));
    if found.history < qos.history {
        return refuse(format!(
            "its history size is {}, expected at least {}: a client that opens it late would \
             not be handed the last sample, and would wait for the next (forever, from an idle \
             daemon); {CREATED_ELSEWHERE}",
            found.history, qos.history
        ));
    }
    if !found.safe_overflow {
        return refuse(format!(
            "its safe overflow is off, expected on: a full subscriber buffer would refuse the \
             newest samples instead of losing its oldest; {CREATED_ELSEWHERE}"
        ));
    }
    let mut warnings = vec![];
    if found.max_publishers < qos.max_publishers {
        warnings.push(QosWarning::FewerPublishers {
            service: name.to_string(),
            found: found.max_publishers,
            expected: qos.max_publishers,
        });
    }
    if found.max_buffer < qos.max_buffer {
        warnings.push(QosWarning::SmallerBuffer {
            service: name.to_string(),
            found: found.max_buffer,
            expected: qos.max_buffer,
        });
    }
    Ok(warnings)
}

/// The warnings [`check_service_settings`] gives for service `name` as `factory` has it
/// (none for a service whose settings it refuses, which [`open_or_create_pubsub`] did
/// not open).
pub fn service_warnings<T: std::fmt::Debug + ZeroCopySend>(
    name: &str,
    factory: &PubSubFactory<Svc, T, ()>,
    qos: Qos,
) -> Vec<QosWarning> {
    check_service_settings(name, ServiceSettings::of(factory), qos).unwrap_or_default()
}

/// Why service `sn` could not be opened for payload `T`: its type, and the existing
/// service's when iceoryx2 can read it (its static configuration, one small file).
fn incompatible_types<T: ZeroCopySend>(node: &IpcNode, sn: &ServiceName) -> String {
    use iceoryx2::service::static_config::message_type_details::{TypeDetail, TypeVariant};
    let ours = TypeDetail::new::<T>(TypeVariant::FixedSize);
    let theirs = existing_payload(node, sn)
        .map(|(name, size, align)| {
            format!(
                " it carries {:?} ({size} B, alignment {align});",
                vlsync_common::text::clip(&name)
            )
        })
        .unwrap_or_default();
    format!(
        "its payload type is not vlsync's {:?} ({} B, alignment {}):{theirs} a vlsync of \
         another version, or another program, created it (stop it, or give each its own \
         --prefix)",
        ours.type_name().to_string(),
        ours.size(),
        ours.alignment()
    )
}

/// The payload type name, size and alignment of existing publish-subscribe service `sn`.
fn existing_payload(node: &IpcNode, sn: &ServiceName) -> Option<(String, usize, usize)> {
    use iceoryx2::service::messaging_pattern::MessagingPattern as Pattern;
    use iceoryx2::service::static_config::messaging_pattern::MessagingPattern;
    use iceoryx2::service::Service as _;
    let d = Svc::details(sn, node.config(), Pattern::PublishSubscribe).ok()??;
    match d.static_details.messaging_pattern() {
        MessagingPattern::PublishSubscribe(c) => {
            let p = c.message_type_details().payload;
            Some((p.type_name().to_string(), p.size(), p.alignment()))
        }
        _ => None,
    }
}

/// Opens or creates event service `name` (default QoS, more nodes for restarts).
pub fn open_or_create_event(node: &IpcNode, name: &str) -> Result<EventFactory<Svc>, IpcError> {
    let sn = service_name(name)?;
    let mut last = String::new();
    for _ in 0..OPEN_ATTEMPTS {
        match node.service_builder(&sn).event().open() {
            Ok(s) => return Ok(s),
            Err(EventOpenError::DoesNotExist) => match node
                .service_builder(&sn)
                .event()
                .max_nodes(48)
                .max_notifiers(16)
                .max_listeners(16)
                .create()
            {
                Ok(s) => return Ok(s),
                Err(e) => last = format!("create failed: {e:?}"),
            },
            Err(e) => last = format!("open failed: {e:?}"),
        }
        std::thread::sleep(OPEN_RETRY);
    }
    Err(IpcError::new(format!("open event service {name:?}"), last))
}

/// The subscriber buffer actually granted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubscriberBuffer {
    /// What was asked for.
    pub requested: usize,
    /// What the service allows (`min(requested, service maximum)`).
    pub granted: usize,
}

/// A subscriber of `factory` with `buffer` samples (clamped to the service maximum).
pub fn subscriber<T: std::fmt::Debug + ZeroCopySend>(
    factory: &PubSubFactory<Svc, T, ()>,
    buffer: usize,
    what: &str,
) -> Result<(Subscriber<Svc, T, ()>, SubscriberBuffer), IpcError> {
    subscriber_telling(factory, buffer, what, || {})
}

/// [`subscriber`], calling `on_unconnected` whenever a publisher that joined the
/// service cannot be connected (its data segment cannot be mapped: memory, file
/// descriptors, another user's files). iceoryx2 then reads the other publishers
/// and tries that one again only when a publisher joins or leaves; by default it
/// would only log a warning, from the reading thread. `on_unconnected` runs on the
/// thread that receives: it must not block or allocate there (count, e.g.).
pub fn subscriber_telling<T: std::fmt::Debug + ZeroCopySend>(
    factory: &PubSubFactory<Svc, T, ()>,
    buffer: usize,
    what: &str,
    on_unconnected: impl Fn() + Send + 'static,
) -> Result<(Subscriber<Svc, T, ()>, SubscriberBuffer), IpcError> {
    let max = factory.static_config().subscriber_max_buffer_size();
    let granted = buffer.clamp(1, max.max(1));
    let sub = factory
        .subscriber_builder()
        .buffer_size(granted)
        .set_degradation_handler(move |_, _: &iceoryx2::port::DegradationInfo| {
            on_unconnected();
            iceoryx2::port::DegradationAction::Ignore
        })
        .create()
        .map_err(|e| IpcError::new(format!("create subscriber on {what}"), format!("{e:?}")))?;
    Ok((
        sub,
        SubscriberBuffer {
            requested: buffer,
            granted,
        },
    ))
}

/// A publisher of `factory` that never blocks (a missing or slow subscriber
/// loses samples; the publisher goes on).
pub fn publisher<T: std::fmt::Debug + ZeroCopySend>(
    factory: &PubSubFactory<Svc, T, ()>,
    what: &str,
) -> Result<Publisher<Svc, T, ()>, IpcError> {
    factory
        .publisher_builder()
        .backpressure_strategy(BackpressureStrategy::DiscardData)
        .create()
        .map_err(|e| IpcError::new(format!("create publisher on {what}"), format!("{e:?}")))
}

/// [`publisher`], calling `on_degraded` whenever a subscriber that joined cannot be
/// connected or its connection is found corrupt at a send (a crashed or foreign
/// subscriber): that subscriber is left out, the others are served. By default
/// iceoryx2 would log an error at every send, from the sending thread.
/// `on_degraded` runs on the thread that sends: it must not block or allocate
/// there (count, e.g.).
pub fn publisher_telling<T: std::fmt::Debug + ZeroCopySend>(
    factory: &PubSubFactory<Svc, T, ()>,
    what: &str,
    on_degraded: impl Fn() + Send + 'static,
) -> Result<Publisher<Svc, T, ()>, IpcError> {
    factory
        .publisher_builder()
        .backpressure_strategy(BackpressureStrategy::DiscardData)
        .set_degradation_handler(move |_, _: &iceoryx2::port::DegradationInfo| {
            on_degraded();
            iceoryx2::port::DegradationAction::Ignore
        })
        .create()
        .map_err(|e| IpcError::new(format!("create publisher on {what}"), format!("{e:?}")))
}

/// A notifier on event service `factory`.
pub fn notifier(factory: &EventFactory<Svc>, what: &str) -> Result<Notifier<Svc>, IpcError> {
    factory
        .notifier_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create notifier on {what}"), format!("{e:?}")))
}

/// A listener on event service `factory`.
pub fn listener(factory: &EventFactory<Svc>, what: &str) -> Result<Listener<Svc>, IpcError> {
    factory
        .listener_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create listener on {what}"), format!("{e:?}")))
}

/// Publishes one signature stream: the driver side.
pub struct SignaturePublisher {
    stream: Stream,
    publisher: Publisher<Svc, SignatureSample, ()>,
    notifier: Notifier<Svc>,
    next_seq: u64,
    unreached: u64,
    unwoken: u64,
    /// Every sample marked [`vlsync_common::wire::FLAG_SIMULATED`] ([`Self::set_simulated`]).
    simulated: bool,
    _services: (PubSubFactory<Svc, SignatureSample, ()>, EventFactory<Svc>),
}

impl SignaturePublisher {
    /// Opens `<prefix>/<stream>/signature` and `<prefix>/signature/ready`, creating
    /// the stream's service for subscriber buffers of up to [`DEFAULT_SIGNATURE_BUFFER`]
    /// samples when it is missing ([`Self::open_sized`] for more).
    pub fn open(node: &IpcNode, names: &ServiceNames, stream: Stream) -> Result<Self, IpcError> {
        Self::open_sized(node, names, stream, DEFAULT_SIGNATURE_BUFFER)
    }

    /// [`Self::open`], creating a missing service for subscriber buffers of up to
    /// `subscriber_buffer` samples (`services.subscriber_buffer`; at least
    /// [`DEFAULT_SIGNATURE_BUFFER`]): a service keeps what its creator set, so a daemon
    /// started after its drivers gets the buffer the configuration asks for only if
    /// the drivers created the services for it.
    pub fn open_sized(
        node: &IpcNode,
        names: &ServiceNames,
        stream: Stream,
        subscriber_buffer: usize,
    ) -> Result<Self, IpcError> {
        let name = names.signature(stream);
        let svc = open_or_create_pubsub::<SignatureSample>(
            node,
            &name,
            Qos::signature(subscriber_buffer),
        )?;
        let ev = open_or_create_event(node, &names.signature_ready())?;
        let publisher = publisher(&svc, &name)?;
        let notifier = notifier(&ev, &names.signature_ready())?;
        Ok(Self {
            stream,
            publisher,
            notifier,
            next_seq: 0,
            unreached: 0,
            unwoken: 0,
            simulated: false,
            _services: (svc, ev),
        })
    }

    /// Marks every sample [`Self::publish`] sends from now on as simulated
    /// ([`vlsync_common::wire::FLAG_SIMULATED`]: a simulator's, not a sensor's), or not.
    pub fn set_simulated(&mut self, on: bool) {
        self.simulated = on;
    }

    /// Publishes one sample stamped with the next sequence number and now
    /// (`CLOCK_MONOTONIC`), then wakes the daemon. The first sample carries
    /// [`vlsync_common::wire::FLAG_FIRST`]. Returns the sequence number used; a
    /// sample no subscriber was connected for is counted ([`Self::unreached`]).
    pub fn publish(&mut self, t_ns: Nanos, value: f64) -> Result<u64, IpcError> {
        let seq = self.next_seq;
        let mut s = SignatureSample::new(t_ns, value, seq, monotonic_ns());
        if seq == 0 {
            s.flags |= vlsync_common::wire::FLAG_FIRST;
        }
        if self.simulated {
            s.flags |= vlsync_common::wire::FLAG_SIMULATED;
        }
        // the sample is out once sent, whether or not the wake-up after it fails:
        // its sequence number is used (reusing it would repeat a number, and a second
        // FLAG_FIRST would look like a driver restart), and it is published (the
        // daemon reads it at its next wake-up, within 0.1 s); a failed wake-up is
        // counted ([`Self::unwoken`])
        if self.send(s)? == 0 {
            self.unreached += 1;
        }
        self.next_seq += 1;
        if self.notify().is_err() {
            self.unwoken += 1;
        }
        Ok(seq)
    }

    /// Samples [`Self::publish`] sent whose wake-up of the daemon failed (it read
    /// them at its next periodic wake-up instead).
    pub fn unwoken(&self) -> u64 {
        self.unwoken
    }

    /// Samples [`Self::publish`] sent while no subscriber (no daemon) was connected:
    /// nobody received them.
    pub fn unreached(&self) -> u64 {
        self.unreached
    }

    /// Publishes a payload exactly as given (tests use it to send hostile samples).
    /// Returns how many subscribers it was delivered to (0: no daemon connected).
    pub fn publish_raw(&self, s: SignatureSample) -> Result<usize, IpcError> {
        let recipients = self.send(s)?;
        self.notify()?;
        Ok(recipients)
    }

    /// Sends `s`; returns how many subscribers it reached.
    fn send(&self, s: SignatureSample) -> Result<usize, IpcError> {
        let what = || format!("publish {} signature", self.stream);
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| IpcError::new(what(), format!("{e:?}")))?;
        sample
            .write_payload(s)
            .send()
            .map_err(|e| IpcError::new(what(), format!("{e:?}")))
    }

    /// Wakes the daemon with this stream's event id.
    fn notify(&self) -> Result<(), IpcError> {
        self.notifier
            .notify_with_custom_event_id(stream_event_id(self.stream))
            .map(|_| ())
            .map_err(|e| {
                IpcError::new(
                    format!("wake the daemon after a {} signature", self.stream),
                    format!("{e:?}"),
                )
            })
    }
}

/// Subscribes to one signature stream beside the daemon: what a recorder
/// (`vlsyncd record`) or a monitor reads. The signature services allow four
/// subscribers, the daemon being one; safe overflow means a subscriber that falls
/// behind loses its own oldest samples (a gap in their sequence numbers) and
/// slows neither the drivers nor the daemon.
pub struct SignatureSubscriber {
    subscriber: Subscriber<Svc, SignatureSample, ()>,
    buffer: SubscriberBuffer,
    /// `<prefix>/<stream>/signature`, for error messages.
    service: String,
    _service: PubSubFactory<Svc, SignatureSample, ()>,
}

impl SignatureSubscriber {
    /// Opens (or creates, with the QoS the drivers would for `services.subscriber_buffer`
    /// = `service_buffer`) `<prefix>/<stream>/signature` and subscribes with `buffer`
    /// samples, clamped to the service's maximum ([`Self::buffer`] says what was
    /// granted).
    pub fn open(
        node: &IpcNode,
        names: &ServiceNames,
        stream: Stream,
        service_buffer: usize,
        buffer: usize,
    ) -> Result<Self, IpcError> {
        let service = names.signature(stream);
        let svc = open_or_create_pubsub::<SignatureSample>(
            node,
            &service,
            Qos::signature(service_buffer),
        )?;
        let (subscriber, buffer) = subscriber(&svc, buffer, &service)?;
        Ok(Self {
            subscriber,
            buffer,
            service,
            _service: svc,
        })
    }

    /// The buffer asked for and the one granted.
    pub fn buffer(&self) -> SubscriberBuffer {
        self.buffer
    }

    /// The oldest pending sample, as published (unvalidated: see
    /// [`SignatureSample::validate`]); `Ok(None)` when none is pending.
    pub fn receive(&mut self) -> Result<Option<SignatureSample>, IpcError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => Ok(Some(*s.payload())),
            Ok(None) => Ok(None),
            Err(e) => Err(IpcError::new(
                format!("receive on `{}`", self.service),
                format!("{e:?}"),
            )),
        }
    }
}

/// The longest single sleep of [`OffsetClient::wait_next`],
/// [`OffsetClient::wait_all`] and [`OffsetClient::wait_one`]; a longer timeout sleeps again. The last estimate
/// handed to a new subscriber (history 1) comes without an event, so a client that
/// opened while the daemon publishes nothing sees it when its slice ends: within
/// 0.35 s of the open (the daemon hands it over within about 0.1 s, busy or idle).
const MAX_WAIT_SLICE: Duration = Duration::from_millis(250);

/// Wake-ups in a row on the offset event that found no valid estimate, after which a
/// wait sleeps out its slice ([`MAX_WAIT_SLICE`]) instead of listening: a process that
/// notifies the event in a loop (or floods it with invalid payloads) would otherwise
/// keep the waiting thread busy until its deadline.
const MAX_EMPTY_WAKES: u32 = 64;

/// The shortest wait a client hands to its listener. iceoryx2 passes the timeout on
/// to the socket (`SO_RCVTIMEO`) in whole microseconds, and a zero there means "no
/// timeout" on Linux: a wait of less than a microsecond would last until the next
/// notification, forever while the daemon is down. A shorter remainder is slept out
/// instead (the kernel rounds a socket timeout up to a clock tick anyway).
const MIN_EVENT_WAIT: Duration = Duration::from_millis(1);

/// How a client takes the next payload off its subscriber: [`receive_copy`]. A field
/// of the client's, so that a test can make a receive fail.
type ReceiveFn<T> = fn(&Subscriber<Svc, T, ()>) -> Result<Option<T>, ReceiveError>;

/// The next pending payload of `subscriber`, copied out (the sample is released at
/// once, so a client never holds one between calls).
fn receive_copy<T: std::fmt::Debug + ZeroCopySend + Copy>(
    subscriber: &Subscriber<Svc, T, ()>,
) -> Result<Option<T>, ReceiveError> {
    Ok(subscriber.receive()?.map(|s| *s.payload()))
}

/// The most receives one call makes whatever the service's creator set (the daemon's
/// own services give 16 × 2).
const MAX_RECEIVES_PER_CALL: usize = 1024;

/// How many receives one call of a client makes at most: what its subscriber can hold
/// (`buffer` per publisher, `max_publishers` of them), at least 1 and at most
/// [`MAX_RECEIVES_PER_CALL`]. Everything pending when the call began fits, so only a
/// publisher that publishes faster than the client reads meets the bound: the call then
/// returns (the rest waits for the next call) instead of looping, its vector growing.
fn receive_cap(buffer: usize, max_publishers: usize) -> usize {
    buffer
        .max(1)
        .saturating_mul(max_publishers.max(1))
        .min(MAX_RECEIVES_PER_CALL)
}

/// Whether `deadline` (`None`: none) has passed.
fn passed(deadline: Option<Instant>) -> bool {
    deadline.is_some_and(|d| Instant::now() >= d)
}

/// How far ahead of `CLOCK_MONOTONIC` a publish time may be and still count as age 0
/// ([`estimate_age_at`]): a second.
pub const FUTURE_MARGIN_NS: Nanos = 1_000_000_000;

/// The age of an estimate published (`publish_ns`, the daemon's `CLOCK_MONOTONIC`)
/// when the clock reads `now_ns`: `now_ns - publish_ns`, saturating, so any pair of
/// values gives an answer (a hostile `publish_ns` of `i64::MIN` too). A publish time up
/// to [`FUTURE_MARGIN_NS`] ahead is age 0; one further ahead, which the same
/// machine's daemon never gives (another clock, or a faulty publisher on the service),
/// is `i64::MAX`, so that every age check fails rather than pass for as long as that
/// stamp lies ahead.
///
/// ```
/// use vlsync_ipc::estimate_age_at;
/// assert_eq!(estimate_age_at(10_000, 7_000), 3_000);
/// assert_eq!(estimate_age_at(10_000, i64::MIN), i64::MAX);
/// assert_eq!(estimate_age_at(0, i64::MAX), i64::MAX);
/// ```
pub fn estimate_age_at(now_ns: Nanos, publish_ns: Nanos) -> i64 {
    let age = now_ns.saturating_sub(publish_ns);
    if age < -FUTURE_MARGIN_NS {
        i64::MAX
    } else {
        age.max(0)
    }
}

/// [`estimate_age_at`] now ([`monotonic_ns`]): how old an estimate published at
/// `publish_ns` is, ns. Its state alone does not tell a live lock: after the daemon
/// stops, its last estimate stays `tracking` (or `holding`).
pub fn estimate_age_ns(publish_ns: Nanos) -> i64 {
    estimate_age_at(monotonic_ns(), publish_ns)
}

/// Whether a valid estimate published at `candidate` becomes the latest one, after the
/// one published at `current` (`None`: none yet): the one published last (the greater
/// `publish_ns`; the later arrival on a tie), whichever publisher it comes from (a dead
/// daemon's port beside the new daemon's hands over its last estimate too). A latest
/// whose publish time lies more than [`FUTURE_MARGIN_NS`] ahead of `now` (read only
/// then) is no newest (another clock, a hostile publisher): it would hold the latest for
/// as long as it lies ahead, so the next valid estimate replaces it.
fn replaces_latest(current: Option<Nanos>, candidate: Nanos, now: impl FnOnce() -> Nanos) -> bool {
    match current {
        None => true,
        Some(c) if candidate >= c => true,
        Some(c) => now().saturating_add(FUTURE_MARGIN_NS) < c,
    }
}

/// A camera stamp on the LiDAR time base ([`OffsetClient::camera_to_lidar`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conversion {
    /// The stamp on the LiDAR clock, ns.
    pub t_lidar_ns: Nanos,
    /// One standard deviation of `t_lidar_ns`, seconds: the offset's at that time.
    pub std_s: f64,
    /// The estimate it was converted with (its state, reference time, sequence number).
    pub estimate: Estimate,
}

/// A valid estimate a client took off its subscriber.
struct Taken {
    estimate: Estimate,
    /// When the daemon published it (`CLOCK_MONOTONIC`, as published).
    publish_ns: Nanos,
    /// Whether it became the client's latest ([`replaces_latest`]).
    newest: bool,
}

/// Subscribes to the daemon's estimates: the client API.
///
/// ```no_run
/// let mut c = vlsync_ipc::OffsetClient::open("vlsync/robot").unwrap();
/// if let Some(e) = c.wait_next(std::time::Duration::from_secs(1)).unwrap() {
///     println!("offset {} s", e.offset_s);
/// }
/// if let Some(c) = c.camera_to_lidar(1_000_000_000) {
///     if c.estimate.state == vlsync_common::EstimatorState::Tracking {
///         println!("LiDAR time {} ns ± {} s", c.t_lidar_ns, c.std_s);
///     }
/// }
/// ```
///
/// Every call that receives takes at most what the subscriber can hold (its buffer of
/// 16 for each publisher the service allows), so a publisher faster than the client
/// cannot keep a call looping; the waits sleep out their slice after
/// 64 wake-ups in a row without a valid estimate, so a process
/// that notifies the offset event in a loop cannot keep them busy (a signal then ends
/// such a wait only at the slice's end).
pub struct OffsetClient {
    subscriber: Subscriber<Svc, OffsetEstimate, ()>,
    listener: Listener<Svc>,
    latest: Option<Estimate>,
    latest_publish_ns: Nanos,
    invalid: u64,
    /// A receive failure met after [`OffsetClient::wait_all`] had taken estimates: those
    /// were handed out, and the next call that receives reports it.
    deferred: Option<IpcError>,
    /// Takes a payload off `subscriber` ([`receive_copy`]).
    receive: ReceiveFn<OffsetEstimate>,
    /// `<prefix>/offset`, for error messages.
    service: String,
    /// Offset random walk (s/√s) while tracking and otherwise, for conversions.
    walk: (f64, f64),
    /// Receives one call makes at most ([`receive_cap`]).
    max_receives: usize,
    /// The subscriber buffer asked for and granted.
    buffer: SubscriberBuffer,
    /// What [`check_service_settings`] said of a service another process created.
    warnings: Vec<QosWarning>,
    _services: (PubSubFactory<Svc, OffsetEstimate, ()>, EventFactory<Svc>),
    _node: IpcNode,
}

impl OffsetClient {
    /// Opens `<prefix>/offset` with its own node (signals not handled: the
    /// application owns SIGINT/SIGTERM). A service another program created with
    /// settings vlsync cannot work with is an error naming the setting
    /// ([`check_service_settings`]); lesser differences are
    /// [`OffsetClient::qos_warnings`].
    pub fn open(prefix: &str) -> Result<Self, IpcError> {
        let names = ServiceNames::new(prefix)?;
        let node = create_node("vlsync-client", false)?;
        let name = names.offset();
        let svc = open_or_create_pubsub::<OffsetEstimate>(&node, &name, Qos::latest())?;
        let warnings = service_warnings(&name, &svc, Qos::latest());
        let ev = open_or_create_event(&node, &name)?;
        let (subscriber, buffer) = subscriber(&svc, 16, &name)?;
        let listener = listener(&ev, &name)?;
        let c = Self {
            subscriber,
            listener,
            latest: None,
            latest_publish_ns: 0,
            invalid: 0,
            deferred: None,
            receive: receive_copy,
            max_receives: receive_cap(buffer.granted, svc.static_config().max_publishers()),
            buffer,
            warnings,
            service: name,
            walk: {
                let d = vlsync_config::EstimatorConfig::default();
                (d.offset_process_noise, d.hold_process_noise)
            },
            _services: (svc, ev),
            _node: node,
        };
        // nothing is taken here: the daemon's last estimate before this open (the
        // service's history, delivered when the daemon next updates its connections,
        // during or after this call) is then always the first `wait_one`/`wait_all`
        // hands out, where draining it here made that depend on the timing
        Ok(c)
    }

    /// Settings of `<prefix>/offset` below vlsync's, when another program created it
    /// (empty otherwise): vlsync works with them, and the caller may say so.
    pub fn qos_warnings(&self) -> &[QosWarning] {
        &self.warnings
    }

    /// The subscriber buffer asked for (16) and granted (less when another program
    /// created the service with smaller buffers).
    pub fn buffer(&self) -> SubscriberBuffer {
        self.buffer
    }

    /// The next valid pending estimate with its publish time, skipping (and
    /// counting, [`OffsetClient::invalid_count`]) payloads validation refuses; at most
    /// `budget` receives (each taken from it). The latest estimate becomes this one
    /// when it was published last ([`replaces_latest`]). A receive failure kept by an
    /// earlier [`OffsetClient::wait_all`] is returned first.
    fn next_valid_within(&mut self, budget: &mut usize) -> Result<Option<Taken>, IpcError> {
        if let Some(e) = self.deferred.take() {
            return Err(e);
        }
        while *budget > 0 {
            *budget -= 1;
            let w = (self.receive)(&self.subscriber).map_err(|e| {
                IpcError::new(format!("receive on `{}`", self.service), format!("{e:?}"))
            })?;
            let Some(w) = w else { return Ok(None) };
            match Estimate::try_from(&w) {
                Ok(e) => {
                    let current = self.latest.map(|_| self.latest_publish_ns);
                    let newest = replaces_latest(current, w.publish_ns, monotonic_ns);
                    if newest {
                        self.latest = Some(e);
                        self.latest_publish_ns = w.publish_ns;
                    }
                    return Ok(Some(Taken {
                        estimate: e,
                        publish_ns: w.publish_ns,
                        newest,
                    }));
                }
                Err(_) => self.invalid += 1,
            }
        }
        Ok(None)
    }

    /// Takes every pending estimate (at most [`receive_cap`] receives); returns whether
    /// one of them became the latest. A valid one published before the latest (a
    /// second publisher on the service, such as a dead daemon's port with samples still
    /// queued) is taken but is no new estimate: [`OffsetClient::wait_next`] would
    /// otherwise hand out the unchanged latest again.
    fn drain(&mut self) -> Result<bool, IpcError> {
        let mut budget = self.max_receives;
        let mut replaced = false;
        while let Some(t) = self.next_valid_within(&mut budget)? {
            replaced |= t.newest;
        }
        Ok(replaced)
    }

    /// Sleeps on the offset event until `deadline` (`None`: no deadline), at most
    /// [`MAX_WAIT_SLICE`] at a time. `Ok(false)`: a signal interrupted it, and the
    /// caller returns what it has, so the application's own handler (Ctrl-C, a job
    /// control stop) is acted on at once. It never asks iceoryx2 whether a
    /// termination was requested: that would install iceoryx2's signal handlers in
    /// an application that owns its signals.
    ///
    /// `empty_wakes`: the caller's count of wake-ups in a row after which it found
    /// nothing (each call is one: the caller returns when it finds something); from
    /// [`MAX_EMPTY_WAKES`] on, the slice is slept out without listening.
    fn wait_event(
        &mut self,
        deadline: Option<Instant>,
        empty_wakes: &mut u32,
    ) -> Result<bool, IpcError> {
        let left = deadline.map_or(MAX_WAIT_SLICE, |d| {
            d.saturating_duration_since(Instant::now())
                .min(MAX_WAIT_SLICE)
        });
        if left < MIN_EVENT_WAIT {
            // too short to hand to the listener (see MIN_EVENT_WAIT): sleeping it out
            // keeps the deadline, and the caller then takes what arrived meanwhile
            std::thread::sleep(left);
            return Ok(true);
        }
        if *empty_wakes >= MAX_EMPTY_WAKES {
            *empty_wakes = 0;
            std::thread::sleep(left);
            return Ok(true);
        }
        let started = Instant::now();
        match self.listener.timed_wait(|_| {}, left) {
            Ok(notifications) => {
                // a timeout starts the count again: only wake-ups before it flood,
                // with notifications or without (any datagram on the listener's
                // socket, which a local process can write, ends the wait with none).
                // Half the slice counts as the timeout, since the kernel may end one
                // up to a clock tick early.
                let timed_out = notifications == 0 && started.elapsed() >= left / 2;
                *empty_wakes = if timed_out {
                    0
                } else {
                    empty_wakes.saturating_add(1)
                };
                Ok(true)
            }
            Err(ListenerWaitError::InterruptSignal) => Ok(false),
            Err(e) => Err(IpcError::new(
                format!("wait on the event of `{}`", self.service),
                format!("{e:?}"),
            )),
        }
    }

    /// The most recent estimate received (after draining what is pending): of those
    /// received, the valid one published last (`publish_ns`), whichever publisher it
    /// came from (a dead daemon's port, not yet reclaimed beside the new daemon's, may
    /// hand over its last estimate after the new one's). A failed receive is not
    /// reported: the last good estimate is returned ([`OffsetClient::try_latest`]
    /// reports it), nor is one an earlier [`OffsetClient::wait_all`] kept. After the
    /// daemon stops, its last estimate stays, in the state it had: judge its age by
    /// [`OffsetClient::latest_age_ns`].
    pub fn latest(&mut self) -> Option<Estimate> {
        // a receive error keeps the last good estimate; one kept from an earlier
        // `wait_all` is dropped first, or it would stand in for this call's drain
        // and leave newer estimates pending
        self.deferred = None;
        let _ = self.drain();
        self.latest
    }

    /// [`OffsetClient::latest`] with a failed receive as the error; the estimates
    /// taken before it stay the latest (which [`OffsetClient::latest`] still returns).
    pub fn try_latest(&mut self) -> Result<Option<Estimate>, IpcError> {
        self.drain()?;
        Ok(self.latest)
    }

    /// `CLOCK_MONOTONIC` time at which the daemon published [`OffsetClient::latest`]
    /// (0 before the first; as published: any value, from a faulty publisher, so age it
    /// with [`estimate_age_ns`], never by subtracting it yourself).
    pub fn latest_publish_ns(&self) -> Nanos {
        self.latest_publish_ns
    }

    /// How old [`OffsetClient::latest`] is now, ns ([`estimate_age_ns`] of its publish
    /// time: never negative, never an overflow, `i64::MAX` for a publish time further
    /// than [`FUTURE_MARGIN_NS`] ahead); `None` before the first estimate. It takes
    /// nothing pending: call it after [`OffsetClient::latest`] or a conversion.
    pub fn latest_age_ns(&self) -> Option<i64> {
        self.latest.map(|_| estimate_age_ns(self.latest_publish_ns))
    }

    /// Payloads refused by validation so far.
    pub fn invalid_count(&self) -> u64 {
        self.invalid
    }

    /// Converts a camera timestamp to the LiDAR time base with the latest estimate
    /// (after draining what is pending), extrapolated with its drift
    /// ([`Estimate::camera_to_lidar`]). `None` before the first estimate.
    ///
    /// The standard deviation includes the offset's random walk from the estimate's
    /// reference time to the stamp ([`Estimate::offset_std_with_walk`]) at the
    /// shipped `estimator.offset_process_noise` while tracking and
    /// `estimator.hold_process_noise` in every other state (an upper bound in a
    /// short hold: the estimator itself switches to the hold walk only once a whole
    /// window passed without a measurement); a daemon configured otherwise is
    /// matched with [`OffsetClient::set_process_noise`]. The
    /// estimate used comes with the result: check its `state` (a `lost` or
    /// `acquiring` estimate is no lock) and its age, [`OffsetClient::latest_age_ns`]
    /// (after the daemon stops its last estimate stays, still `tracking`; `t_ref_ns`
    /// is on the LiDAR clock and says nothing about it), before trusting the stamp.
    /// Draining here means a recorder that also calls
    /// [`OffsetClient::wait_all`] misses the estimates this call took.
    pub fn camera_to_lidar(&mut self, t_cam_ns: Nanos) -> Option<Conversion> {
        let e = self.latest()?;
        let t_lidar_ns = e.camera_to_lidar(t_cam_ns);
        let walk = if e.state == EstimatorState::Tracking {
            self.walk.0
        } else {
            self.walk.1
        };
        Some(Conversion {
            t_lidar_ns,
            std_s: e.offset_std_with_walk(t_lidar_ns, walk),
            estimate: e,
        })
    }

    /// The offset's random walk (s/√s) [`OffsetClient::camera_to_lidar`] assumes while
    /// tracking and otherwise: the daemon's `estimator.offset_process_noise` and
    /// `estimator.hold_process_noise` (shipped: 2e-4 and 3e-3). Values that are not
    /// finite and >= 0 are refused and leave the setting as it was.
    pub fn set_process_noise(&mut self, tracking: f64, holding: f64) -> Result<(), IpcError> {
        for (name, v) in [("tracking", tracking), ("holding", holding)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(IpcError::new(
                    "set_process_noise",
                    format!("{name} walk {v} is not a finite number >= 0"),
                ));
            }
        }
        self.walk = (tracking, holding);
        Ok(())
    }

    /// Every valid estimate pending, in order, each with the `CLOCK_MONOTONIC` time
    /// the daemon published it (what a recorder needs: [`OffsetClient::wait_next`]
    /// keeps only the newest). The first is the daemon's last estimate before
    /// [`OffsetClient::open`], when it had one (its publish time says so). Waits up to `timeout` on the offset event when none
    /// is pending; an empty vector on timeout, and early when a signal interrupts the
    /// wait. The subscriber buffers 16 estimates (8 s at the default hop): a caller
    /// that sleeps longer loses the oldest. One call returns at most what the
    /// subscriber can hold (16 for each publisher the service allows): the rest of a
    /// faster publisher's estimates wait for the next call. A receive that fails after
    /// estimates were taken does not lose them: they are returned, and the failure is
    /// the error of the next call that receives.
    pub fn wait_all(&mut self, timeout: Duration) -> Result<Vec<(Estimate, Nanos)>, IpcError> {
        let deadline = Instant::now().checked_add(timeout);
        let mut out = vec![];
        let mut interrupted = false;
        let mut empty_wakes = 0;
        loop {
            let mut budget = self.max_receives;
            loop {
                match self.next_valid_within(&mut budget) {
                    Ok(Some(t)) => out.push((t.estimate, t.publish_ns)),
                    Ok(None) => break,
                    // estimates taken off the subscriber exist nowhere else
                    Err(e) if !out.is_empty() => {
                        self.deferred = Some(e);
                        return Ok(out);
                    }
                    Err(e) => return Err(e),
                }
            }
            if !out.is_empty() || interrupted || passed(deadline) {
                return Ok(out);
            }
            interrupted = !self.wait_event(deadline, &mut empty_wakes)?;
        }
    }

    /// The oldest valid estimate pending, with the `CLOCK_MONOTONIC` time the daemon
    /// published it: every estimate, one per call, in order of arrival, from the
    /// daemon's last one before [`OffsetClient::open`] when it had one (the C API's
    /// `vlsync_client_wait_one`; [`OffsetClient::wait_all`] without its vector). Waits
    /// up to `timeout` on the offset event when none is pending: `Ok(None)` on
    /// timeout, and early when a signal interrupts the wait. The subscriber buffers 16
    /// estimates: a caller that falls further behind loses the oldest.
    pub fn wait_one(&mut self, timeout: Duration) -> Result<Option<(Estimate, Nanos)>, IpcError> {
        let deadline = Instant::now().checked_add(timeout);
        let mut interrupted = false;
        let mut empty_wakes = 0;
        loop {
            let mut budget = self.max_receives;
            if let Some(t) = self.next_valid_within(&mut budget)? {
                return Ok(Some((t.estimate, t.publish_ns)));
            }
            if interrupted || passed(deadline) {
                return Ok(None);
            }
            interrupted = !self.wait_event(deadline, &mut empty_wakes)?;
        }
    }

    /// Waits up to `timeout` for the next estimate; sleeps on the offset event.
    /// `Ok(None)` on timeout, and early when a signal interrupts the wait (the
    /// caller checks its own stop flag and calls again). A `timeout` too long for
    /// the clock (`Duration::MAX`) waits with no deadline. What it returns is
    /// [`OffsetClient::latest`] once a valid estimate arrived that became it: one
    /// published before the latest (a second publisher on the service) is taken
    /// without ending the wait.
    pub fn wait_next(&mut self, timeout: Duration) -> Result<Option<Estimate>, IpcError> {
        let deadline = Instant::now().checked_add(timeout);
        let mut interrupted = false;
        let mut empty_wakes = 0;
        loop {
            if self.drain()? {
                return Ok(self.latest);
            }
            if interrupted || passed(deadline) {
                return Ok(None);
            }
            interrupted = !self.wait_event(deadline, &mut empty_wakes)?;
        }
    }
}

/// Subscribes to the daemon's status.
pub struct StatusClient {
    subscriber: Subscriber<Svc, Status, ()>,
    latest: Option<Status>,
    /// Payloads validation refused so far.
    invalid: u64,
    /// A receive failure met after [`StatusClient::receive_all`] had taken payloads:
    /// the next call reports it.
    deferred: Option<IpcError>,
    /// Takes a payload off `subscriber` ([`receive_copy`]).
    receive: ReceiveFn<Status>,
    /// `<prefix>/status`, for error messages.
    service: String,
    /// Receives one call makes at most ([`receive_cap`]).
    max_receives: usize,
    /// What [`check_service_settings`] said of a service another process created.
    warnings: Vec<QosWarning>,
    _service: PubSubFactory<Svc, Status, ()>,
    _node: IpcNode,
}

impl StatusClient {
    /// Opens `<prefix>/status` (a service another program created with settings vlsync
    /// cannot work with is an error, [`check_service_settings`]; lesser differences are
    /// [`StatusClient::qos_warnings`]).
    pub fn open(prefix: &str) -> Result<Self, IpcError> {
        let names = ServiceNames::new(prefix)?;
        let node = create_node("vlsync-status-client", false)?;
        let name = names.status();
        let svc = open_or_create_pubsub::<Status>(&node, &name, Qos::latest())?;
        let warnings = service_warnings(&name, &svc, Qos::latest());
        let (subscriber, buffer) = subscriber(&svc, 16, &name)?;
        Ok(Self {
            subscriber,
            latest: None,
            invalid: 0,
            deferred: None,
            receive: receive_copy,
            max_receives: receive_cap(buffer.granted, svc.static_config().max_publishers()),
            warnings,
            service: name,
            _service: svc,
            _node: node,
        })
    }

    /// Settings of `<prefix>/status` below vlsync's, when another program created it
    /// (empty otherwise): vlsync works with them, and the caller may say so.
    pub fn qos_warnings(&self) -> &[QosWarning] {
        &self.warnings
    }

    /// Every valid status pending, oldest first (the subscriber buffers 16);
    /// invalid payloads are skipped and the last validation error returned when
    /// nothing valid arrived. One call takes at most what the subscriber can hold (16
    /// for each publisher the service allows): the rest of a faster publisher's
    /// statuses wait for the next call. A receive that fails after payloads were
    /// taken is the next call's error: this one returns what it took (or the
    /// validation error), so a call that counted invalid payloads never fails for
    /// another reason (the C API's `vlsync_status_latest` relies on it).
    pub fn receive_all(&mut self) -> Result<Vec<Status>, WireErrorOrIpc> {
        if let Some(e) = self.deferred.take() {
            return Err(WireErrorOrIpc::Ipc(e));
        }
        let mut out = vec![];
        let mut last_err = None;
        for _ in 0..self.max_receives {
            let st = match (self.receive)(&self.subscriber) {
                Ok(Some(st)) => st,
                Ok(None) => break,
                Err(e) => {
                    let e =
                        IpcError::new(format!("receive on `{}`", self.service), format!("{e:?}"));
                    if out.is_empty() && last_err.is_none() {
                        return Err(WireErrorOrIpc::Ipc(e));
                    }
                    // what this call took is its result (statuses taken off the
                    // subscriber exist nowhere else; invalid ones counted give their
                    // validation error): the failure is the next call's
                    self.deferred = Some(e);
                    break;
                }
            };
            match st.validate() {
                Ok(()) => {
                    self.latest = Some(st);
                    out.push(st);
                }
                Err(e) => {
                    self.invalid += 1;
                    last_err = Some(e);
                }
            }
        }
        match (out.is_empty(), last_err) {
            (true, Some(e)) => Err(WireErrorOrIpc::Wire(e)),
            _ => Ok(out),
        }
    }

    /// Status payloads validation refused so far (skipped by [`Self::receive_all`]
    /// and [`Self::latest`]).
    pub fn invalid_count(&self) -> u64 {
        self.invalid
    }

    /// The most recent valid status; invalid payloads are skipped (the validation
    /// error is returned only while no valid status ever arrived).
    pub fn latest(&mut self) -> Result<Option<Status>, WireErrorOrIpc> {
        match self.receive_all() {
            Err(WireErrorOrIpc::Wire(e)) if self.latest.is_none() => Err(WireErrorOrIpc::Wire(e)),
            Ok(_) | Err(WireErrorOrIpc::Wire(_)) => Ok(self.latest),
            Err(e) => Err(e),
        }
    }
}

/// An IPC failure or an invalid payload.
#[derive(Debug, Clone, PartialEq)]
pub enum WireErrorOrIpc {
    /// Transport failure.
    Ipc(IpcError),
    /// The payload failed validation.
    Wire(WireError),
}

impl fmt::Display for WireErrorOrIpc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WireErrorOrIpc::Ipc(e) => e.fmt(f),
            WireErrorOrIpc::Wire(e) => write!(f, "invalid status payload: {e}"),
        }
    }
}

impl std::error::Error for WireErrorOrIpc {}

#[cfg(test)]
mod tests {
    use super::*;

    fn unique_prefix(tag: &str) -> String {
        format!("vlsync-test/{tag}-{}", std::process::id())
    }

    #[test]
    fn names_follow_the_prefix() {
        let n = ServiceNames::new("a/b").unwrap();
        assert_eq!(n.signature(Stream::Cam), "a/b/cam/signature");
        assert_eq!(n.signature(Stream::Lidar), "a/b/lidar/signature");
        assert_eq!(n.offset(), "a/b/offset");
        assert_eq!(n.status(), "a/b/status");
        assert_eq!(n.signature_ready(), "a/b/signature/ready");
        let e = ServiceNames::new("/bad").unwrap_err();
        assert!(e.to_string().contains("services.prefix"), "{e}");
    }

    #[test]
    fn a_driver_creates_the_service_for_the_configured_buffer() {
        let names = ServiceNames::new(&unique_prefix("sized")).unwrap();
        let node = create_node("test", false).unwrap();
        let _p = SignaturePublisher::open_sized(&node, &names, Stream::Cam, 1024).unwrap();
        let _q = SignaturePublisher::open(&node, &names, Stream::Lidar).unwrap();
        for (stream, max) in [
            (Stream::Cam, 1024),
            (Stream::Lidar, DEFAULT_SIGNATURE_BUFFER),
        ] {
            let svc = open_or_create_pubsub::<SignatureSample>(
                &node,
                &names.signature(stream),
                Qos::signature(4096),
            )
            .unwrap();
            assert_eq!(svc.static_config().subscriber_max_buffer_size(), max);
            let (_sub, buf) = subscriber(&svc, 4096, "sig").unwrap();
            assert_eq!(buf.granted, max);
        }
    }

    #[test]
    fn signature_roundtrip_and_wakeup() {
        let names = ServiceNames::new(&unique_prefix("sig")).unwrap();
        let node = create_node("test", false).unwrap();
        let mut p = SignaturePublisher::open(&node, &names, Stream::Lidar).unwrap();
        let svc = open_or_create_pubsub::<SignatureSample>(
            &node,
            &names.signature(Stream::Lidar),
            Qos::signature(1024),
        )
        .unwrap();
        // opening never constrains: the service keeps what its creator set
        assert_eq!(
            svc.static_config().subscriber_max_buffer_size(),
            DEFAULT_SIGNATURE_BUFFER
        );
        let (sub, buf) = subscriber(&svc, 1024, "lidar").unwrap();
        assert_eq!(buf.granted, DEFAULT_SIGNATURE_BUFFER);
        let ev = open_or_create_event(&node, &names.signature_ready()).unwrap();
        let l = listener(&ev, "ready").unwrap();
        assert_eq!(p.publish(5, 1.5).unwrap(), 0);
        assert_eq!(p.publish(6, 2.5).unwrap(), 1);
        let mut ids = vec![];
        l.timed_wait(|a| ids.push(a.id.as_value()), Duration::from_secs(1))
            .unwrap();
        assert_eq!(ids, vec![1]);
        let a = *sub.receive().unwrap().unwrap().payload();
        assert!(a.is_first());
        assert_eq!((a.t_ns, a.value, a.seq), (5, 1.5, 0));
        let b = *sub.receive().unwrap().unwrap().payload();
        assert!(!b.is_first());
        assert_eq!((b.t_ns, b.seq), (6, 1));
        assert!(b.publish_ns >= a.publish_ns && a.publish_ns > 0);
    }

    #[test]
    fn offset_client_sees_estimates_and_refuses_garbage() {
        let names = ServiceNames::new(&unique_prefix("off")).unwrap();
        let node = create_node("test-daemon", false).unwrap();
        let svc =
            open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
        let ev = open_or_create_event(&node, &names.offset()).unwrap();
        let publ = publisher(&svc, "offset").unwrap();
        let noti = notifier(&ev, "offset").unwrap();
        let mut c = OffsetClient::open(&names.prefix).unwrap();
        assert!(c.latest().is_none());
        assert!(c.camera_to_lidar(0).is_none());
        let e = estimate(3);
        let mut bad = OffsetEstimate::from_estimate(&e, 1).unwrap();
        bad.state = 77;
        publ.send_copy(bad).unwrap();
        publ.send_copy(OffsetEstimate::from_estimate(&e, 2).unwrap())
            .unwrap();
        noti.notify().unwrap();
        let got = c.wait_next(Duration::from_secs(1)).unwrap().unwrap();
        assert_eq!(got.seq, 3);
        assert_eq!(c.invalid_count(), 1);
        let conv = c.camera_to_lidar(5_000_000_000).unwrap();
        assert_eq!(conv.t_lidar_ns, 5_020_000_000);
        assert_eq!(conv.estimate.seq, 3);
        // 4.98 s from t_ref at the shipped tracking walk of 2e-4 s/√s
        let want = (1e-6f64 + 4e-8 * 4.98).sqrt();
        assert!((conv.std_s - want).abs() < 1e-12, "{}", conv.std_s);
        // a holding estimate walks at the holding rate; a refused rate changes nothing
        assert!(c.set_process_noise(f64::NAN, 1.0).is_err());
        c.set_process_noise(0.0, 1e-3).unwrap();
        let held = Estimate {
            seq: 4,
            state: vlsync_common::EstimatorState::Holding,
            ..e
        };
        publ.send_copy(OffsetEstimate::from_estimate(&held, 3).unwrap())
            .unwrap();
        let conv = c.camera_to_lidar(5_000_000_000).unwrap();
        assert_eq!(conv.estimate.state, vlsync_common::EstimatorState::Holding);
        let want = (1e-6f64 + 1e-6 * 4.98).sqrt();
        assert!((conv.std_s - want).abs() < 1e-12, "{}", conv.std_s);
        // "wait forever" is a timeout too long for the clock, not a panic
        publ.send_copy(OffsetEstimate::from_estimate(&Estimate { seq: 5, ..e }, 4).unwrap())
            .unwrap();
        let got = c.wait_next(Duration::MAX).unwrap().unwrap();
        assert_eq!(got.seq, 5);
        // nothing more: times out
        let t0 = Instant::now();
        assert!(c.wait_next(Duration::from_millis(100)).unwrap().is_none());
        assert!(t0.elapsed() >= Duration::from_millis(90));
        // wait_all keeps every estimate, in order, with its publish time
        for (seq, publish) in [(6, 30), (7, 40)] {
            let e = Estimate { seq, ..e };
            publ.send_copy(OffsetEstimate::from_estimate(&e, publish).unwrap())
                .unwrap();
        }
        publ.send_copy(bad).unwrap();
        noti.notify().unwrap();
        let all = c.wait_all(Duration::from_secs(1)).unwrap();
        let seqs: Vec<(u64, i64)> = all.iter().map(|(e, p)| (e.seq, *p)).collect();
        assert_eq!(seqs, vec![(6, 30), (7, 40)]);
        assert_eq!(c.invalid_count(), 2);
        assert!(c.wait_all(Duration::from_millis(50)).unwrap().is_empty());
        // wait_one hands out the same, one per call, skipping the invalid
        for (seq, publish) in [(8, 50), (9, 60)] {
            let e = Estimate { seq, ..e };
            publ.send_copy(OffsetEstimate::from_estimate(&e, publish).unwrap())
                .unwrap();
            publ.send_copy(bad).unwrap();
        }
        noti.notify().unwrap();
        let mut one = || {
            c.wait_one(Duration::from_secs(1))
                .unwrap()
                .map(|(e, p)| (e.seq, p))
        };
        assert_eq!(one(), Some((8, 50)));
        assert_eq!(one(), Some((9, 60)));
        let t0 = Instant::now();
        assert_eq!(
            c.wait_one(Duration::from_millis(100))
                .unwrap()
                .map(|x| x.0.seq),
            None
        );
        assert!(t0.elapsed() >= Duration::from_millis(90));
        assert_eq!(c.invalid_count(), 4);
    }

    fn estimate(seq: u64) -> Estimate {
        Estimate {
            seq,
            t_ref_ns: 10_000_000_000,
            offset_s: 0.02,
            drift: 0.0,
            offset_std_s: 0.001,
            drift_std: 0.0,
            state: vlsync_common::EstimatorState::Tracking,
            polarity: vlsync_common::Polarity::Positive,
            peak_score: 0.8,
            peak_ratio: 2.0,
            measured_offset_s: 0.02,
        }
    }

    /// The settings vlsync cannot work with are errors naming service, setting, found
    /// and expected; the lesser ones are warnings; more than vlsync's is fine.
    #[test]
    fn an_opened_service_is_checked_against_our_qos() {
        let ours = |q: Qos| ServiceSettings {
            history: q.history,
            max_buffer: q.max_buffer,
            max_publishers: q.max_publishers,
            safe_overflow: true,
        };
        let name = "vlsync/robot/offset";
        assert_eq!(
            check_service_settings(name, ours(Qos::latest()), Qos::latest()),
            Ok(vec![])
        );
        // iceoryx2's defaults, as a C++ node would create it
        let defaults = ServiceSettings {
            history: 0,
            max_buffer: 2,
            max_publishers: 2,
            safe_overflow: true,
        };
        let e = check_service_settings(name, defaults, Qos::latest()).unwrap_err();
        let text = e.to_string();
        for part in [
            "\"vlsync/robot/offset\"",
            "history size is 0, expected at least 1",
            "forever",
            "another program",
        ] {
            assert!(text.contains(part), "{part:?} in {text}");
        }
        let e = check_service_settings(
            name,
            ServiceSettings {
                safe_overflow: false,
                ..ours(Qos::latest())
            },
            Qos::latest(),
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("safe overflow is off, expected on"),
            "{e}"
        );
        // a signature service wants no history, and a smaller one still works
        let sig = Qos::signature(1024);
        let found = ServiceSettings {
            history: 0,
            max_buffer: 256,
            max_publishers: 2,
            safe_overflow: true,
        };
        let w = check_service_settings("p/cam/signature", found, sig).unwrap();
        assert_eq!(
            w,
            vec![
                QosWarning::FewerPublishers {
                    service: "p/cam/signature".into(),
                    found: 2,
                    expected: 4
                },
                QosWarning::SmallerBuffer {
                    service: "p/cam/signature".into(),
                    found: 256,
                    expected: 1024
                }
            ]
        );
        assert!(w[0]
            .to_string()
            .starts_with("service `p/cam/signature` allows 2 publishers at once, vlsync creates it with 4: another program"));
        // more than ours: nothing to say
        let more = ServiceSettings {
            history: 5,
            max_buffer: 4096,
            max_publishers: 9,
            safe_overflow: true,
        };
        assert_eq!(
            check_service_settings(name, more, Qos::latest()),
            Ok(vec![])
        );
    }

    /// A C++ node with iceoryx2's defaults created the offset service first: the
    /// client refuses it, saying why, instead of waiting forever for an estimate an
    /// idle daemon never hands over (no history).
    #[test]
    fn a_client_refuses_an_offset_service_without_history() {
        let names = ServiceNames::new(&unique_prefix("foreign-qos")).unwrap();
        let node = create_node("test-foreign", false).unwrap();
        let sn = ServiceName::new(&names.offset()).unwrap();
        let _svc = node
            .service_builder(&sn)
            .publish_subscribe::<OffsetEstimate>()
            .history_size(0)
            .subscriber_max_buffer_size(2)
            .create()
            .unwrap();
        let e = OffsetClient::open(&names.prefix).err().expect("refused");
        assert!(e.context.contains(&names.offset()), "{e}");
        assert!(
            e.message.contains("history size is 0, expected at least 1"),
            "{e}"
        );
        let e = StatusClient::open(&names.prefix).err();
        assert!(e.is_none(), "the status service was not created by it");
    }

    /// Another payload type on a service: the error names ours and theirs.
    #[test]
    fn a_service_of_another_type_is_refused_naming_both_types() {
        let names = ServiceNames::new(&unique_prefix("foreign-type")).unwrap();
        let node = create_node("test-foreign", false).unwrap();
        let name = names.signature(Stream::Cam);
        let sn = ServiceName::new(&name).unwrap();
        let _svc = node
            .service_builder(&sn)
            .publish_subscribe::<u64>()
            .create()
            .unwrap();
        let e = open_or_create_pubsub::<SignatureSample>(&node, &name, Qos::signature(256))
            .expect_err("refused");
        let text = e.to_string();
        for part in [
            name.as_str(),
            "\"vlsync.SignatureSample.v1\" (40 B, alignment 8)",
            "\"u64\" (8 B, alignment 8)",
            "a vlsync of another version, or another program",
        ] {
            assert!(text.contains(part), "{part:?} in {text}");
        }
    }

    #[test]
    fn an_age_saturates_and_a_far_future_stamp_is_the_oldest() {
        const S: i64 = 1_000_000_000;
        assert_eq!(estimate_age_at(10 * S, 7 * S), 3 * S);
        assert_eq!(estimate_age_at(10 * S, 10 * S + S / 2), 0);
        assert_eq!(estimate_age_at(10 * S, 10 * S + FUTURE_MARGIN_NS), 0);
        assert_eq!(
            estimate_age_at(10 * S, 10 * S + FUTURE_MARGIN_NS + 1),
            i64::MAX
        );
        assert_eq!(estimate_age_at(10 * S, i64::MAX), i64::MAX);
        assert_eq!(estimate_age_at(10 * S, i64::MIN), i64::MAX);
        assert_eq!(estimate_age_at(i64::MAX, i64::MIN), i64::MAX);
        assert_eq!(estimate_age_at(i64::MIN, i64::MAX), i64::MAX);
        assert_eq!(estimate_age_ns(i64::MIN), i64::MAX);
    }

    #[test]
    fn the_latest_is_the_one_published_last() {
        let now = || 50;
        assert!(replaces_latest(None, i64::MIN, now));
        assert!(replaces_latest(Some(10), 20, now));
        assert!(replaces_latest(Some(10), 10, now));
        assert!(!replaces_latest(Some(20), 10, now));
        // a latest far in the future is replaced by the next (it would hold for good)
        assert!(replaces_latest(Some(i64::MAX), 10, now));
        assert!(!replaces_latest(Some(50 + FUTURE_MARGIN_NS), 10, now));
        assert!(replaces_latest(Some(51 + FUTURE_MARGIN_NS), 10, now));
        assert!(!replaces_latest(Some(i64::MAX), 10, || i64::MAX));
    }

    /// Two publishers on the offset service (a dead daemon's port beside the new
    /// one's): `latest` is the estimate published last, whichever arrives last (iceoryx2
    /// hands out the ports' samples in the order of the ports, here the dead one's
    /// last); `wait_one` still hands out every estimate; a hostile publish time is aged
    /// safely.
    #[test]
    fn latest_keeps_the_newest_of_two_publishers() {
        let names = ServiceNames::new(&unique_prefix("two-pub")).unwrap();
        let node = create_node("test-daemon", false).unwrap();
        let svc =
            open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
        let new = publisher(&svc, "offset").unwrap();
        let old = publisher(&svc, "offset").unwrap();
        let mut c = OffsetClient::open(&names.prefix).unwrap();
        assert_eq!(c.latest_age_ns(), None);
        assert!(c.qos_warnings().is_empty());
        assert_eq!(c.buffer().granted, 16);
        let now = monotonic_ns();
        let send = |p: &Publisher<Svc, OffsetEstimate, ()>, seq, publish_ns| {
            p.send_copy(OffsetEstimate::from_estimate(&estimate(seq), publish_ns).unwrap())
                .unwrap();
        };
        // sent in either order: the newer publish time wins
        send(&new, 1, now);
        send(&old, 2, now - 1_000_000_000);
        assert_eq!(c.latest().unwrap().seq, 1);
        assert_eq!(c.latest_publish_ns(), now);
        send(&old, 3, now - 1_000_000_000);
        send(&new, 4, now + 1);
        assert_eq!(c.latest().unwrap().seq, 4);
        assert_eq!(c.latest_publish_ns(), now + 1);
        assert!(c.latest_age_ns().is_some_and(|a| a >= 0));
        // wait_one still hands out both
        send(&new, 5, now + 2);
        send(&old, 6, now - 5);
        let mut got = vec![];
        while let Some((e, _)) = c.wait_one(Duration::ZERO).unwrap() {
            got.push(e.seq);
        }
        got.sort_unstable();
        assert_eq!(got, vec![5, 6]);
        assert_eq!(c.latest().unwrap().seq, 5);
        // a hostile publish time far ahead is replaced by the next, and at the
        // other end of the range it is aged without overflow
        send(&old, 7, i64::MAX);
        assert_eq!(c.latest().unwrap().seq, 7);
        assert_eq!(c.latest_age_ns(), Some(i64::MAX));
        send(&old, 8, i64::MIN);
        assert_eq!(c.latest().unwrap().seq, 8);
        assert_eq!(c.latest_publish_ns(), i64::MIN);
        assert_eq!(c.latest_age_ns(), Some(i64::MAX));
    }

    #[test]
    fn a_call_receives_at_most_what_the_subscriber_can_hold() {
        assert_eq!(receive_cap(16, 2), 32);
        assert_eq!(receive_cap(0, 0), 1);
        assert_eq!(receive_cap(usize::MAX, usize::MAX), MAX_RECEIVES_PER_CALL);
    }

    /// A thread of the test's that opens what it needs on `prefix` through its own
    /// node (`setup`), then runs the step `setup` returns in a loop until stopped
    /// (dropped too, so that a failing test leaves no thread flooding the next).
    struct Flood {
        stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
        thread: Option<std::thread::JoinHandle<()>>,
    }

    impl Flood {
        fn start<S: FnMut()>(
            prefix: &str,
            setup: impl FnOnce(&ServiceNames, &IpcNode) -> S + Send + 'static,
        ) -> Self {
            let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            let (flag, prefix) = (stop.clone(), prefix.to_string());
            let thread = std::thread::spawn(move || {
                let names = ServiceNames::new(&prefix).unwrap();
                let node = create_node("test-flood", false).unwrap();
                let mut step = setup(&names, &node);
                while !flag.load(std::sync::atomic::Ordering::Relaxed) {
                    step();
                }
            });
            Self {
                stop,
                thread: Some(thread),
            }
        }

        /// Stops the thread and fails the test if it failed.
        fn finish(mut self) {
            self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
            self.thread.take().unwrap().join().unwrap();
        }
    }

    impl Drop for Flood {
        fn drop(&mut self) {
            self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
            if let Some(t) = self.thread.take() {
                let _ = t.join();
            }
        }
    }

    /// A publisher flooding faster than the client reads: every call returns, with at
    /// most what the subscriber can hold.
    #[test]
    fn a_flooding_publisher_cannot_keep_a_call_looping() {
        let names = ServiceNames::new(&unique_prefix("flood")).unwrap();
        let mut status = StatusClient::open(&names.prefix).unwrap();
        let mut offsets = OffsetClient::open(&names.prefix).unwrap();
        let flood = Flood::start(&names.prefix, |names, node| {
            let st = open_or_create_pubsub::<Status>(node, &names.status(), Qos::latest()).unwrap();
            let off = open_or_create_pubsub::<OffsetEstimate>(node, &names.offset(), Qos::latest())
                .unwrap();
            let ev = open_or_create_event(node, &names.offset()).unwrap();
            let (sp, op, n) = (
                publisher(&st, "status").unwrap(),
                publisher(&off, "offset").unwrap(),
                notifier(&ev, "offset").unwrap(),
            );
            let mut k = 0;
            move || {
                k += 1;
                let _ = sp.send_copy(Status {
                    estimates_published: k,
                    ..Status::default()
                });
                let _ = op.send_copy(OffsetEstimate::from_estimate(&estimate(k), 1).unwrap());
                let _ = n.notify();
            }
        });
        let (cap_status, cap_offsets) = (status.max_receives, offsets.max_receives);
        assert_eq!((cap_status, cap_offsets), (32, 32));
        let mut seen = 0;
        for _ in 0..200 {
            let got = status.receive_all().unwrap();
            assert!(got.len() <= cap_status, "{}", got.len());
            let got = offsets.wait_all(Duration::from_millis(10)).unwrap();
            assert!(got.len() <= cap_offsets, "{}", got.len());
            seen += got.len();
            let _ = offsets.latest();
        }
        flood.finish();
        assert!(seen > 0);
    }

    /// A process notifying the offset event in a loop without publishing: a wait
    /// sleeps out its slices after 64 empty wake-ups instead of spinning through
    /// them (its thread's CPU time stays a small part of the wait).
    #[test]
    fn a_notification_flood_does_not_keep_a_wait_busy() {
        let names = ServiceNames::new(&unique_prefix("notify-flood")).unwrap();
        let mut c = OffsetClient::open(&names.prefix).unwrap();
        let flood = Flood::start(&names.prefix, |names, node| {
            let ev = open_or_create_event(node, &names.offset()).unwrap();
            let n = notifier(&ev, "offset").unwrap();
            move || {
                let _ = n.notify();
            }
        });
        let cpu0 = rt::thread_cpu_ns().unwrap();
        assert!(c.wait_one(Duration::from_millis(600)).unwrap().is_none());
        assert!(c.wait_next(Duration::from_millis(600)).unwrap().is_none());
        let cpu = rt::thread_cpu_ns().unwrap() - cpu0;
        flood.finish();
        // spinning, the two waits took ~1.2 s of CPU; sleeping out the slices, a few ms
        assert!(cpu < 300_000_000, "{cpu} ns of CPU in 1.2 s of waits");
    }

    #[test]
    fn status_client_receives_every_pending_status() {
        let names = ServiceNames::new(&unique_prefix("status")).unwrap();
        let node = create_node("test-daemon", false).unwrap();
        let svc = open_or_create_pubsub::<Status>(&node, &names.status(), Qos::latest()).unwrap();
        let publ = publisher(&svc, "status").unwrap();
        let mut c = StatusClient::open(&names.prefix).unwrap();
        assert!(c.receive_all().unwrap().is_empty());
        for n in 1..=3 {
            publ.send_copy(Status {
                estimates_published: n,
                ..Status::default()
            })
            .unwrap();
        }
        let got: Vec<u64> = c
            .receive_all()
            .unwrap()
            .iter()
            .map(|s| s.estimates_published)
            .collect();
        assert_eq!(got, vec![1, 2, 3]);
        assert_eq!(c.latest().unwrap().unwrap().estimates_published, 3);
        publ.send_copy(Status {
            degraded: 9,
            ..Status::default()
        })
        .unwrap();
        assert!(matches!(c.receive_all(), Err(WireErrorOrIpc::Wire(_))));
        // latest() skips an invalid one and keeps the last good status
        publ.send_copy(Status {
            degraded: 9,
            ..Status::default()
        })
        .unwrap();
        assert_eq!(c.latest().unwrap().unwrap().estimates_published, 3);
        assert_eq!(c.invalid_count(), 2);
    }

    /// A wait whose deadline has passed, or lies less than a microsecond ahead,
    /// returns: handed to the listener, its remainder became a socket timeout of zero,
    /// which Linux takes as none, and the wait lasted until the next notification
    /// (forever here, where nobody notifies).
    #[test]
    fn a_wait_at_its_deadline_returns() {
        let prefix = unique_prefix("deadline");
        let (tx, rx) = std::sync::mpsc::channel();
        // on its own thread, so that a wait that never returns fails the test
        std::thread::spawn(move || {
            let mut c = OffsetClient::open(&prefix).unwrap();
            for ahead in [Duration::ZERO, Duration::from_nanos(500)] {
                let r = c.wait_event(Some(Instant::now() + ahead), &mut 0);
                assert!(matches!(r, Ok(true)), "{r:?}");
            }
            assert!(c.wait_next(Duration::from_nanos(900)).unwrap().is_none());
            assert!(c.wait_one(Duration::from_nanos(1)).unwrap().is_none());
            assert!(c.wait_all(Duration::from_nanos(1)).unwrap().is_empty());
            let _ = tx.send(());
        });
        rx.recv_timeout(Duration::from_secs(5))
            .expect("a wait at its deadline did not return");
    }

    /// Datagrams without a notification written to the listener's socket by another
    /// local process end each wait at once with nothing: the waits sleep out their
    /// slices after 64 of them, as for a notification flood, instead of spinning
    /// (such a wake-up used to count as a timeout, which starts the count again).
    #[test]
    fn raw_datagrams_on_the_listener_do_not_keep_a_wait_busy() {
        let names = ServiceNames::new(&unique_prefix("raw-datagrams")).unwrap();
        let mut c = OffsetClient::open(&names.prefix).unwrap();
        // the listener's socket: `<root><prefix><listener id><suffix>` in iceoryx2 0.10
        let cfg = iceoryx2::config::Config::global_config();
        let socket = std::path::PathBuf::from(format!(
            "{}{}{}{}",
            cfg.global.root_path(),
            cfg.global.prefix,
            c.listener.id().value(),
            cfg.global.service.event_connection_suffix
        ));
        assert!(socket.exists(), "no socket at {}", socket.display());
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flood = {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let s = std::os::unix::net::UnixDatagram::unbound().unwrap();
                s.set_nonblocking(true).unwrap();
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    // a full socket buffer refuses some: the flood goes on
                    let _ = s.send_to(&[7], &socket);
                }
            })
        };
        let cpu0 = rt::thread_cpu_ns().unwrap();
        assert!(c.wait_next(Duration::from_millis(600)).unwrap().is_none());
        let cpu = rt::thread_cpu_ns().unwrap() - cpu0;
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        flood.join().unwrap();
        assert!(cpu < 300_000_000, "{cpu} ns of CPU in a 0.6 s wait");
    }

    /// An estimate published before the latest (a second publisher on the service: a
    /// dead daemon's port with samples still queued) is taken without ending
    /// `wait_next`, which used to hand out the unchanged latest again for it.
    #[test]
    fn an_older_estimate_is_no_next_estimate() {
        let names = ServiceNames::new(&unique_prefix("older")).unwrap();
        let node = create_node("test-daemon", false).unwrap();
        let svc =
            open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
        let (new, old) = (
            publisher(&svc, "offset").unwrap(),
            publisher(&svc, "offset").unwrap(),
        );
        let mut c = OffsetClient::open(&names.prefix).unwrap();
        let send = |p: &Publisher<Svc, OffsetEstimate, ()>, seq, publish_ns| {
            p.send_copy(OffsetEstimate::from_estimate(&estimate(seq), publish_ns).unwrap())
                .unwrap();
        };
        send(&new, 1, 2_000);
        assert_eq!(c.wait_next(Duration::from_secs(1)).unwrap().unwrap().seq, 1);
        send(&old, 9, 1_000);
        assert!(c.wait_next(Duration::from_millis(50)).unwrap().is_none());
        assert_eq!(c.latest().unwrap().seq, 1);
        send(&new, 2, 3_000);
        assert_eq!(c.wait_next(Duration::from_secs(1)).unwrap().unwrap().seq, 2);
    }

    thread_local! {
        /// Receives [`failing_receive`] passes on before it fails.
        static RECEIVES_LEFT: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    }

    /// [`receive_copy`] for [`RECEIVES_LEFT`] receives, then a failure.
    fn failing_receive<T: std::fmt::Debug + ZeroCopySend + Copy>(
        s: &Subscriber<Svc, T, ()>,
    ) -> Result<Option<T>, ReceiveError> {
        match RECEIVES_LEFT.get() {
            0 => Err(ReceiveError::ExceedsMaxBorrows),
            n => {
                RECEIVES_LEFT.set(n - 1);
                receive_copy(s)
            }
        }
    }

    /// Three estimates pending on a fresh offset service; a `wait_all` whose third
    /// receive fails returns the first two (the failure kept); then `after`.
    fn two_taken_then_a_failure(tag: &str, after: impl FnOnce(&mut OffsetClient)) {
        let names = ServiceNames::new(&unique_prefix(tag)).unwrap();
        let node = create_node("test-daemon", false).unwrap();
        let svc =
            open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
        let publ = publisher(&svc, "offset").unwrap();
        let mut c = OffsetClient::open(&names.prefix).unwrap();
        for (seq, publish) in [(1, 10), (2, 20), (3, 30)] {
            publ.send_copy(OffsetEstimate::from_estimate(&estimate(seq), publish).unwrap())
                .unwrap();
        }
        c.receive = failing_receive;
        RECEIVES_LEFT.set(2);
        let got: Vec<u64> = c
            .wait_all(Duration::from_secs(1))
            .unwrap()
            .iter()
            .map(|(e, _)| e.seq)
            .collect();
        assert_eq!(got, vec![1, 2]);
        after(&mut c);
    }

    /// A receive that fails after `wait_all` took estimates: they are returned, and
    /// the failure is the next call's error (it used to be returned at once, the
    /// estimates, taken off the subscriber, lost).
    #[test]
    fn wait_all_keeps_what_it_took_before_a_failed_receive() {
        two_taken_then_a_failure("keep-taken", |c| {
            let e = c.wait_all(Duration::from_secs(1)).unwrap_err();
            assert!(e.to_string().contains("ExceedsMaxBorrows"), "{e}");
            // reported once; the receives work again
            c.receive = receive_copy;
            let got = c.wait_all(Duration::from_secs(1)).unwrap();
            assert_eq!(got.iter().map(|(e, _)| e.seq).collect::<Vec<_>>(), vec![3]);
        });
    }

    /// `latest` after a `wait_all` that kept a receive failure drains what is
    /// pending (the kept failure, which `latest` does not report, stood in for its
    /// drain: a conversion used the older estimate with a newer one waiting).
    #[test]
    fn latest_after_a_kept_failure_still_drains() {
        two_taken_then_a_failure("keep-latest", |c| {
            c.receive = receive_copy;
            assert_eq!(c.latest().map(|e| e.seq), Some(3));
        });
    }

    /// The same for the status: what a call took is its result and a failed receive
    /// after it the next call's error, so that a call which counted invalid payloads
    /// returns their validation error, never a transport failure (which the C API's
    /// callers, seeing the invalid count rise, used to take for invalid payloads).
    #[test]
    fn receive_all_reports_a_failure_after_what_it_took() {
        let names = ServiceNames::new(&unique_prefix("status-fail")).unwrap();
        let node = create_node("test-daemon", false).unwrap();
        let svc = open_or_create_pubsub::<Status>(&node, &names.status(), Qos::latest()).unwrap();
        let publ = publisher(&svc, "status").unwrap();
        let mut c = StatusClient::open(&names.prefix).unwrap();
        c.receive = failing_receive;
        let bad = Status {
            degraded: 9,
            ..Status::default()
        };
        publ.send_copy(bad).unwrap();
        RECEIVES_LEFT.set(1);
        assert!(matches!(c.latest(), Err(WireErrorOrIpc::Wire(_))));
        assert_eq!(c.invalid_count(), 1);
        assert!(matches!(c.latest(), Err(WireErrorOrIpc::Ipc(_))));
        assert_eq!(c.invalid_count(), 1);
        // valid statuses taken before a failure are returned, the failure next
        for n in [1, 2] {
            publ.send_copy(Status {
                estimates_published: n,
                ..Status::default()
            })
            .unwrap();
        }
        RECEIVES_LEFT.set(2);
        assert_eq!(c.receive_all().unwrap().len(), 2);
        assert!(matches!(c.receive_all(), Err(WireErrorOrIpc::Ipc(_))));
        // nothing taken: the failure at once
        assert!(matches!(c.receive_all(), Err(WireErrorOrIpc::Ipc(_))));
        c.receive = receive_copy;
        assert!(c.receive_all().unwrap().is_empty());
        assert_eq!(c.latest().unwrap().unwrap().estimates_published, 2);
    }

    /// A signal during an open is tried again, as a service being created is; the
    /// errors given up on blame the payload type only where they are about it.
    #[test]
    fn an_interrupted_open_is_retried_and_refusals_say_why() {
        use PublishSubscribeOpenError as E;
        for e in [
            E::Interrupt,
            E::IsMarkedForDestruction,
            E::HangsInCreation,
            E::InternalFailure,
            E::ServiceInCorruptedState,
        ] {
            assert!(open_is_transient(&e), "{e:?}");
        }
        for e in [
            E::VersionMismatch,
            E::InsufficientPermissions,
            E::ExceedsMaxNumberOfNodes,
            E::IncompatibleMessagingPattern,
            E::UnableToCreateServiceTag,
        ] {
            assert!(!open_is_transient(&e), "{e:?}");
            let why = open_refusal(&e);
            assert!(why.starts_with(&format!("{e:?} (")), "{why}");
            assert!(!why.contains("payload type"), "{why}");
        }
        assert!(open_refusal(&E::VersionMismatch).contains("iceoryx2 version"));
        let why = open_refusal(&E::DoesNotSupportRequestedMinHistorySize);
        assert!(why.contains("payload type or settings"), "{why}");
    }
}
