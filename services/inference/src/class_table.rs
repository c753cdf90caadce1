//! POVNav's class -> navigability lookup (section 4.2): which semantic classes
//! the robot may drive on, and what they cost (for the costmap stages). It can
//! be changed while the stage runs: [`ClassTableFile`] reloads the file when it
//! changes, and a broken edit keeps the previous table (logged), never a
//! half-read one.
//!
//! ```toml
//! default_navigable = false
//! default_cost_s_per_m = 10.0
//!
//! [[class]]
//! id = 1
//! name = "drivable"
//! navigable = true
//! cost_s_per_m = 0.25
//! ```

use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassEntry {
    pub id: u8,
    #[serde(default)]
    pub name: String,
    pub navigable: bool,
    #[serde(default = "lethal")]
    pub cost_s_per_m: f32,
}

fn lethal() -> f32 {
    f32::INFINITY
}

/// The class table file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassTableConfig {
    #[serde(default)]
    pub default_navigable: bool,
    #[serde(default = "lethal")]
    pub default_cost_s_per_m: f32,
    #[serde(default, rename = "class")]
    pub classes: Vec<ClassEntry>,
}

impl Validate for ClassTableConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "default_cost_s_per_m",
            self.default_cost_s_per_m,
            Range::cost_s_per_m(),
        );
        for (i, c) in self.classes.iter().enumerate() {
            r.key(&format!("class[{i}].id"), c.id, Range::between(0.0, 255.0))
                .key(
                    &format!("class[{i}].cost_s_per_m"),
                    c.cost_s_per_m,
                    Range::cost_s_per_m(),
                );
        }
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        let mut seen = [false; 256];
        for (i, c) in self.classes.iter().enumerate() {
            ConfigError::check(
                !seen[c.id as usize],
                &format!("class[{i}].id"),
                c.id,
                "each id listed once",
            )?;
            seen[c.id as usize] = true;
        }
        Ok(())
    }
}

/// Lookup tables built from a [`ClassTableConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct ClassTable {
    navigable: [bool; 256],
    cost_s_per_m: [f32; 256],
}

impl ClassTable {
    pub fn new(config: &ClassTableConfig) -> Self {
        let mut t = Self {
            navigable: [config.default_navigable; 256],
            cost_s_per_m: [config.default_cost_s_per_m; 256],
        };
        for c in &config.classes {
            t.navigable[c.id as usize] = c.navigable;
            t.cost_s_per_m[c.id as usize] = c.cost_s_per_m;
        }
        t
    }

    /// Every class navigable except those listed (`classes` navigable ids).
    pub fn navigable_ids(ids: &[u8]) -> Self {
        let mut t = Self {
            navigable: [false; 256],
            cost_s_per_m: [f32::INFINITY; 256],
        };
        for &i in ids {
            t.navigable[i as usize] = true;
            t.cost_s_per_m[i as usize] = 1.0;
        }
        t
    }

    pub fn is_navigable(&self, class: u8) -> bool {
        self.navigable[class as usize]
    }

    pub fn cost_s_per_m(&self, class: u8) -> f32 {
        self.cost_s_per_m[class as usize]
    }

    /// The navigability image (255 = navigable) of a class id map.
    pub fn navigability(&self, ids: &[u8]) -> Vec<u8> {
        ids.iter()
            .map(|&c| if self.navigable[c as usize] { 255 } else { 0 })
            .collect()
    }
}

/// A class table file that is reloaded when it changes on disk.
pub struct ClassTableFile {
    path: PathBuf,
    modified: Option<SystemTime>,
    table: ClassTable,
    pub reloads: u64,
}

impl ClassTableFile {
    pub fn open(path: &Path) -> Result<Self, ConfigError> {
        let config: ClassTableConfig = farsight_stage::load_config_file(path)?;
        Ok(Self {
            path: path.to_path_buf(),
            modified: std::fs::metadata(path).and_then(|m| m.modified()).ok(),
            table: ClassTable::new(&config),
            reloads: 0,
        })
    }

    pub fn table(&self) -> &ClassTable {
        &self.table
    }

    /// Reloads the file if its modification time changed. Returns `Ok(true)` on
    /// a reload; on a broken file, keeps the current table and returns the error.
    pub fn poll(&mut self) -> Result<bool, ConfigError> {
        let modified = std::fs::metadata(&self.path)
            .and_then(|m| m.modified())
            .ok();
        if modified == self.modified {
            return Ok(false);
        }
        self.modified = modified;
        let config: ClassTableConfig = farsight_stage::load_config_file(&self.path)?;
        self.table = ClassTable::new(&config);
        self.reloads += 1;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_maps_ids_and_defaults() {
        let c: ClassTableConfig = farsight_stage::parse_config(
            "default_navigable = false\n[[class]]\nid = 1\nnavigable = true\ncost_s_per_m = 0.5\n",
            "t.toml",
        )
        .unwrap();
        let t = ClassTable::new(&c);
        assert_eq!(t.navigability(&[0, 1, 2]), vec![0, 255, 0]);
        assert_eq!(t.cost_s_per_m(1), 0.5);
        assert!(t.cost_s_per_m(0).is_infinite());
        let e = farsight_stage::parse_config::<ClassTableConfig>(
            "[[class]]\nid = 3\nnavigable = true\n[[class]]\nid = 3\nnavigable = false\n",
            "t.toml",
        )
        .unwrap_err();
        assert!(
            e.to_string().starts_with("config key `class[1].id` = 3"),
            "{e}"
        );
    }

    #[test]
    fn file_reloads_on_change_and_survives_a_broken_edit() {
        let dir = std::env::temp_dir().join(format!("classtable-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("classes.toml");
        std::fs::write(&path, "[[class]]\nid = 1\nnavigable = true\n").unwrap();
        let mut f = ClassTableFile::open(&path).unwrap();
        assert!(f.table().is_navigable(1));
        assert!(!f.poll().unwrap());
        // mtime resolution can be coarse: make the change visible.
        std::thread::sleep(std::time::Duration::from_millis(20));
        std::fs::write(
            &path,
            "[[class]]\nid = 1\nnavigable = false\n[[class]]\nid = 2\nnavigable = true\n",
        )
        .unwrap();
        let later = SystemTime::now() + std::time::Duration::from_secs(2);
        std::fs::File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(later)
            .unwrap();
        assert!(f.poll().unwrap());
        assert!(!f.table().is_navigable(1) && f.table().is_navigable(2));
        std::fs::write(&path, "[[class]]\nid = \"x\"\n").unwrap();
        std::fs::File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(later + std::time::Duration::from_secs(2))
            .unwrap();
        assert!(f.poll().is_err());
        assert!(
            f.table().is_navigable(2),
            "a broken edit keeps the previous table"
        );
        assert_eq!(f.reloads, 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
