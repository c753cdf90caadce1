//! Each camera's newest model, from its `camera/<name>/info` topic: what a
//! stage needs to know where a pixel looks. A camera stage republishes its
//! model with its frames, so the model can change while a stage runs (a
//! recalibration); tables built from it are then rebuilt. One cache for
//! every stage that projects pixels (bin projection, costmap fusion,
//! POVNav's subgoal selection).

use crate::runtime::{Inbox, Ports};
use farsight_interfaces::camera::{Camera, CameraError};
use farsight_interfaces::msg::CameraInfo;

/// The cameras' names, their info inputs, and the newest valid model of each.
#[derive(Debug, Clone, Default)]
pub struct CameraModels {
    names: Vec<String>,
    ports: Vec<usize>,
    models: Vec<Option<Camera>>,
}

impl CameraModels {
    /// Declares each camera's info topic (once per camera) as an input. It
    /// does not wake the step: a model alone changes no output; it is taken
    /// at the next step, before that step's frames (which it describes).
    pub fn declare<'a>(ports: &mut Ports, names: impl IntoIterator<Item = &'a String>) -> Self {
        let mut unique: Vec<String> = Vec::new();
        for n in names {
            if !unique.contains(n) {
                unique.push(n.clone());
            }
        }
        Self {
            ports: unique
                .iter()
                .map(|c| ports.input(farsight_interfaces::topics::camera_info(c).name()))
                .collect(),
            models: vec![None; unique.len()],
            names: unique,
        }
    }

    /// Takes each camera's newest info. Returns the cameras whose model
    /// changed (their tables must be rebuilt). A bad info goes to `bad`
    /// with the camera's name, and the previous model stays: one broken
    /// message does not blind a camera that was working.
    pub fn refresh(
        &mut self,
        inbox: &mut Inbox,
        mut bad: impl FnMut(&str, CameraError),
    ) -> Vec<usize> {
        let mut changed = Vec::new();
        for (i, &port) in self.ports.iter().enumerate() {
            let Some(info) = inbox.take::<CameraInfo>(port) else {
                continue;
            };
            match Camera::from_info(&info) {
                Ok(c) => {
                    if self.models[i].as_ref() != Some(&c) {
                        changed.push(i);
                    }
                    self.models[i] = Some(c);
                }
                Err(e) => bad(&self.names[i], e),
            }
        }
        changed
    }

    /// Camera `i`'s newest model, if a valid one has arrived.
    pub fn get(&self, i: usize) -> Option<&Camera> {
        self.models.get(i).and_then(Option::as_ref)
    }

    /// The index of camera `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Camera `i`'s name.
    pub fn name(&self, i: usize) -> &str {
        &self.names[i]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};
    use farsight_interfaces::message::Message;
    use farsight_interfaces::msg::Stamp;

    #[test]
    fn the_newest_valid_model_wins_and_a_bad_one_keeps_the_last() {
        let mut ports = Ports::default();
        let names = ["front".to_string(), "front".to_string(), "rear".to_string()];
        let mut models = CameraModels::declare(&mut ports, &names);
        assert_eq!(ports.inputs.len(), 2, "one input per camera");
        let front = Camera::new(
            0,
            "front",
            CameraModel::pinhole(64, 48, 50.0, 50.0, 31.5, 23.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        );
        let mut inbox = Inbox::new(2);
        inbox.put(0, Message::from(front.to_info(Stamp::default())));
        let changed = models.refresh(&mut inbox, |_, e| panic!("{e}"));
        assert_eq!(changed, vec![0]);
        assert_eq!(models.get(0), Some(&front));
        assert!(models.get(1).is_none(), "rear not yet");
        // The same model again is no change; a broken one is reported by name.
        inbox.put(0, Message::from(front.to_info(Stamp::default())));
        assert!(models.refresh(&mut inbox, |_, _| panic!()).is_empty());
        let mut broken = front.to_info(Stamp::default());
        broken.width = 0;
        inbox.put(0, Message::from(broken));
        let mut bad = Vec::new();
        models.refresh(&mut inbox, |name, _| bad.push(name.to_string()));
        assert_eq!(bad, vec!["front"]);
        assert_eq!(models.get(0), Some(&front), "kept");
        assert_eq!(models.index("rear"), Some(1));
        assert_eq!(models.name(1), "rear");
    }
}
