//! The ROS 2 graph as the nodes use it: a context on a domain, topics by their ROS names and
//! message types, and the QoS each topic is used with.

use mapmerge_jobs::JobError;
use mapmerge_rosbag::{OccupancyGridMessage, OCCUPANCY_GRID_TYPE};
use ros2_client::dds::rustdds::QosPolicies;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile, Subscription,
};
use serde::de::DeserializeOwned;
use serde::Serialize;

/// The highest DDS domain a ROS 2 node may join (`ROS_DOMAIN_ID`).
pub const DOMAIN_ID_MAX: u16 = 232;

/// How a subscription hears its publishers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Delivery {
    /// Best effort (ROS's sensor-data QoS): hears reliable and best-effort publishers alike.
    #[default]
    BestEffort,
    /// Reliable: hears reliable publishers only, and loses nothing they send.
    Reliable,
}

/// Messages a subscription keeps before they are taken.
const SUBSCRIPTION_DEPTH: usize = 1000;

impl Delivery {
    /// A sensor subscription's QoS.
    pub(crate) fn qos(self) -> QosProfile {
        let qos = QosProfile::subscription_default().history(History::KeepLast {
            depth: SUBSCRIPTION_DEPTH,
        });
        match self {
            Self::BestEffort => qos.reliability_best_effort(),
            Self::Reliable => qos.reliability_reliable(WhenFull::DEFAULT),
        }
    }
}

/// A latched topic (`/map`, `/tf_static`, the events): reliable and transient-local, as
/// map_server publishes, so late subscribers get the last `depth` messages.
pub(crate) fn latched(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth })
}

/// A reliable, volatile topic (`/tf`).
pub(crate) fn reliable(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth })
}

/// The domain of `ROS_DOMAIN_ID`, else 0; a value that is not a domain is bad input.
pub fn domain_from_env() -> Result<u16, JobError> {
    match std::env::var("ROS_DOMAIN_ID") {
        Ok(text) if !text.trim().is_empty() => check_domain(text.trim().parse().map_err(|_| {
            JobError::bad_input(format!("ROS_DOMAIN_ID={text}: not a domain number"))
        })?),
        _ => Ok(0),
    }
}

/// `domain` if ROS 2 allows it (0–232).
pub fn check_domain(domain: u16) -> Result<u16, JobError> {
    if domain > DOMAIN_ID_MAX {
        return Err(JobError::bad_input(format!(
            "ROS domain {domain} is beyond {DOMAIN_ID_MAX}"
        )));
    }
    Ok(domain)
}

/// A node `name` on `domain`, without rosout or parameter services (it serves nothing).
pub(crate) fn open_node(domain: u16, name: &str) -> Result<(Context, Node), JobError> {
    let context = Context::with_options(ContextOptions::new().domain_id(domain))
        .map_err(|e| JobError::failed(&Failure(format!("ROS 2 domain {domain}: {e:?}"))))?;
    let node_name = NodeName::new("/", name)
        .map_err(|e| JobError::bad_input(format!("node name '{name}': {e:?}")))?;
    let node = context
        .new_node(
            node_name,
            NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .map_err(|e| JobError::failed(&Failure(format!("ROS 2 node '{name}': {e:?}"))))?;
    Ok((context, node))
}

/// A failure of the DDS layer, as an error the jobs' errors can carry.
#[derive(Debug)]
pub(crate) struct Failure(pub String);

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Failure {}

/// `pkg/msg/Type` (the constants of `mapmerge_rosbag`) as ros2-client's type name.
fn type_name(message_type: &str) -> Result<MessageTypeName, JobError> {
    match message_type.split('/').collect::<Vec<_>>().as_slice() {
        [package, "msg", name] => Ok(MessageTypeName::new(package, name)),
        _ => Err(JobError::bad_input(format!(
            "message type '{message_type}' is not pkg/msg/Type"
        ))),
    }
}

/// The topic `name` (a ROS name such as `/scan` or `/robot1/map`) of `message_type`.
fn topic(
    node: &mut Node,
    name: &str,
    message_type: &str,
    qos: &QosProfile,
) -> Result<ros2_client::dds::rustdds::Topic, JobError> {
    let parsed = Name::parse(name)
        .map_err(|e| JobError::bad_input(format!("topic name '{name}': {e:?}")))?;
    node.create_topic(&parsed, type_name(message_type)?, qos)
        .map_err(|e| JobError::failed(&Failure(format!("topic '{name}': {e:?}"))))
}

/// A subscription to `name`.
pub(crate) fn subscribe<M: 'static>(
    node: &mut Node,
    name: &str,
    message_type: &str,
    qos: QosProfile,
) -> Result<Subscription<M>, JobError> {
    let topic = topic(node, name, message_type, &qos)?;
    node.create_subscription(&topic, Some(qos))
        .map_err(|e| JobError::failed(&Failure(format!("subscribing to '{name}': {e:?}"))))
}

/// A publisher on `name`.
pub(crate) fn advertise<M: Serialize>(
    node: &mut Node,
    name: &str,
    message_type: &str,
    qos: QosProfile,
) -> Result<Publisher<M>, JobError> {
    let topic = topic(node, name, message_type, &qos)?;
    node.create_publisher(&topic, Some(qos))
        .map_err(|e| JobError::failed(&Failure(format!("publishing on '{name}': {e:?}"))))
}

/// A latched map writer (reliable, transient-local, one map kept) on the DDS layer itself:
/// a node's last map must reach its subscribers before the node leaves, and only the DDS
/// writer can wait for their acknowledgements (ros2-client's `Publisher` cannot).
pub(crate) struct MapWriter {
    writer: ros2_client::dds::rustdds::no_key::DataWriterCdr<OccupancyGridMessage>,
}

impl MapWriter {
    /// A writer on `name`.
    pub(crate) fn new(context: &Context, node: &mut Node, name: &str) -> Result<Self, JobError> {
        let qos = latched(1);
        let topic = topic(node, name, OCCUPANCY_GRID_TYPE, &qos)?;
        let policies = QosPolicies::from(&qos);
        let failed = |e: &dyn std::fmt::Debug| {
            JobError::failed(&Failure(format!("publishing on '{name}': {e:?}")))
        };
        let writer = context
            .domain_participant()
            .create_publisher(&policies)
            .map_err(|e| failed(&e))?
            .create_datawriter_no_key_cdr::<OccupancyGridMessage>(&topic, Some(policies))
            .map_err(|e| failed(&e))?;
        Ok(Self { writer })
    }

    /// Publishes `map`; false when DDS refused it.
    pub(crate) fn publish(&self, map: OccupancyGridMessage) -> bool {
        self.writer.write(map, None).is_ok()
    }

    /// Waits at most `max_wait` for every subscriber to acknowledge what was published.
    pub(crate) fn flush(&self, max_wait: std::time::Duration) -> bool {
        self.writer
            .wait_for_acknowledgments(max_wait)
            .unwrap_or(false)
    }
}

/// Every message waiting on `subscription`, oldest first; messages that do not decode are
/// counted in `bad`.
pub(crate) fn take_all<M: 'static + DeserializeOwned>(
    subscription: &Subscription<M>,
    bad: &mut usize,
) -> Vec<M> {
    let mut taken = Vec::new();
    loop {
        match subscription.take() {
            Ok(Some((message, _))) => taken.push(message),
            Ok(None) => return taken,
            Err(_) => *bad += 1,
        }
        if taken.len() >= SUBSCRIPTION_DEPTH {
            return taken;
        }
    }
}

/// `std_msgs/msg/String`.
pub(crate) const STRING_TYPE: &str = "std_msgs/msg/String";

/// A ROS 2 stamp from seconds (zero for what `Time` cannot hold).
pub(crate) fn stamp_of(seconds: f64) -> mapmerge_rosbag::Time {
    mapmerge_rosbag::Time::from_nanoseconds((seconds * 1e9).round() as i64).unwrap_or_default()
}

/// Seconds since the Unix epoch, now.
pub(crate) fn now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn type_names_and_domains() {
        let name = type_name(mapmerge_rosbag::LASER_SCAN_TYPE).unwrap();
        assert_eq!(name.dds_msg_type(), "sensor_msgs::msg::dds_::LaserScan_");
        assert!(type_name("LaserScan").is_err());
        assert_eq!(check_domain(232).unwrap(), 232);
        assert!(check_domain(233).unwrap_err().to_string().contains("232"));
    }
}
