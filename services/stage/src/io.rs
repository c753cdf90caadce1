//! What a stage instance reads and writes, given its config: the edges of a
//! graph file (`graphs/*.toml`) are computed from these declarations, not
//! written by hand, so `farsight graph check` sees the graph the stages will
//! really build. Each stage's library declares its own, next to its config
//! ([`DeclaresTopics`]).

use crate::inputs::Need;
use farsight_interfaces::topics::{self, TopicKind};

/// One topic a stage reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Read {
    pub topic: String,
    /// Required: without a writer the stage never produces output.
    /// Optional: the stage works without it (degraded or with a feature off).
    pub need: Need,
    /// Read from the topic's queue of this depth, not its latest value: a
    /// reader that must not lose messages (the recorder). The transport
    /// gives every publisher of the topic a queue
    /// (`farsight_interfaces::transport::ipc`, `FARSIGHT_QUEUES`).
    pub queue_depth: Option<usize>,
}

/// The topics a stage instance reads and writes.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Io {
    pub reads: Vec<Read>,
    pub writes: Vec<String>,
}

impl Io {
    /// Every stage instance writes its health report, `health/<instance>`.
    pub fn for_instance(instance: &str) -> Self {
        Self {
            reads: Vec::new(),
            writes: vec![topics::health(instance).name().to_string()],
        }
    }

    pub fn read(&mut self, topic: impl Into<String>, need: Need) -> &mut Self {
        let topic = topic.into();
        // A topic read twice (a camera in two lists) is one edge, at the
        // stronger need.
        match self.reads.iter_mut().find(|r| r.topic == topic) {
            Some(r) if need == Need::Required => r.need = Need::Required,
            Some(_) => {}
            None => self.reads.push(Read {
                topic,
                need,
                queue_depth: None,
            }),
        }
        self
    }

    /// An optional read from the topic's queue, `depth` messages deep.
    pub fn read_queued(&mut self, topic: impl Into<String>, depth: usize) -> &mut Self {
        let topic = topic.into();
        match self.reads.iter_mut().find(|r| r.topic == topic) {
            Some(r) => r.queue_depth = Some(r.queue_depth.unwrap_or(0).max(depth)),
            None => self.reads.push(Read {
                topic,
                need: Need::Optional,
                queue_depth: Some(depth),
            }),
        }
        self
    }

    pub fn write(&mut self, topic: impl Into<String>) -> &mut Self {
        let topic = topic.into();
        if !self.writes.contains(&topic) {
            self.writes.push(topic);
        }
        self
    }

    /// The message type of every topic, or the first that is not a
    /// farsight topic.
    pub fn kinds(&self) -> Result<Vec<(String, TopicKind)>, String> {
        self.reads
            .iter()
            .map(|r| &r.topic)
            .chain(&self.writes)
            .map(|t| {
                topics::kind_of(t)
                    .map(|k| (t.clone(), k))
                    .ok_or_else(|| format!("`{t}` is not a farsight topic"))
            })
            .collect()
    }
}

/// A stage config that can say what its stage reads and writes. `config_dir`
/// resolves files the config names (a model config says which outputs an
/// inference stage has).
pub trait DeclaresTopics {
    fn topics(&self, instance: &str, config_dir: &std::path::Path) -> Result<Io, String>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_merge_at_the_stronger_need_and_writes_once() {
        let mut io = Io::for_instance("fusion");
        io.read("camera/a/info", Need::Optional)
            .read("camera/a/info", Need::Required)
            .read("camera/a/info", Need::Optional)
            .write("costmap/fused")
            .write("costmap/fused");
        assert_eq!(
            io.reads,
            vec![Read {
                topic: "camera/a/info".into(),
                need: Need::Required,
                queue_depth: None,
            }]
        );
        assert_eq!(io.writes, vec!["health/fusion", "costmap/fused"]);
        assert!(io.kinds().is_ok());
        io.write("not/a/topic");
        assert_eq!(
            io.kinds().unwrap_err(),
            "`not/a/topic` is not a farsight topic"
        );
    }
}
