//! Which scene a run simulates, as the `sim` node's configuration names it: a procedural house
//! (`house:<seed>`, optionally smaller), a large home or office (`home:<seed>`, `office:<seed>`)
//! or a scene file (optionally with its [`Placement`]: up
//! axis, transform, floor levelling). The `sim`
//! operator, the evaluator and `activemap eval` all build their simulator from this one
//! description, so the ground truth is always computed on the scene the robot explored.

use crate::error::{Result, SimError};
use crate::house::{self, HouseConfig, Style};
use crate::load::{LoadOptions, Loaded, Placement, load_scene};
use crate::simulator::{SimConfig, Simulator};
use std::path::Path;

/// A scene to simulate (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct SceneSpec {
    /// `house:<seed>` for a procedural house, or the path of a glTF/GLB, OBJ or PLY scene.
    pub scene: String,
    /// Largest number of rooms of a procedural house (fewer = smaller house).
    pub max_rooms: Option<u32>,
    /// Largest floor area of a procedural house, m².
    pub max_area: Option<f64>,
    /// Where a scene file goes in the world (up axis, transform, floor); the default keeps the
    /// format's up axis and nothing else. Procedural houses refuse every placement key.
    pub placement: Placement,
}

impl SceneSpec {
    /// `scene` with the generator defaults and the default placement (the format's up axis).
    pub fn new(scene: impl Into<String>) -> Self {
        Self {
            scene: scene.into(),
            max_rooms: None,
            max_area: None,
            placement: Placement::default(),
        }
    }

    /// The style and seed of a procedural scene (`house:<seed>`, `home:<seed>` or
    /// `office:<seed>`); `None` for a scene file.
    pub fn procedural(&self) -> Result<Option<(Style, u64)>> {
        let Some((prefix, seed)) = self.scene.split_once(':') else {
            return Ok(None);
        };
        let Some(style) = Style::from_prefix(prefix) else {
            return Ok(None);
        };
        seed.trim()
            .parse()
            .map(|seed| Some((style, seed)))
            .map_err(|_| SimError::InvalidConfig {
                field: "scene",
                value: self.scene.clone(),
                reason: "a procedural scene is `house:<seed>`, `home:<seed>` or `office:<seed>` \
                         with an unsigned integer seed",
            })
    }

    /// Whether the scene is a well-formed procedural one (`house:`, `home:` or `office:` with
    /// a seed), not a scene file.
    pub fn is_procedural(&self) -> bool {
        self.procedural().is_ok_and(|p| p.is_some())
    }

    /// The seed of a procedural scene (any style); `None` for a scene file.
    pub fn house_seed(&self) -> Result<Option<u64>> {
        Ok(self.procedural()?.map(|(_, seed)| seed))
    }

    /// The generator settings: the style's ([`HouseConfig::for_style`]; a scene file gets the
    /// house defaults) narrowed by `max_rooms` and `max_area`.
    pub fn house_config(&self) -> Result<HouseConfig> {
        let style = self.procedural()?.map_or(Style::House, |(style, _)| style);
        let mut config = HouseConfig::for_style(style);
        if let Some(rooms) = self.max_rooms {
            if rooms == 0 {
                return Err(SimError::InvalidConfig {
                    field: "max_rooms",
                    value: rooms.to_string(),
                    reason: "a house has at least 1 room",
                });
            }
            config.max_rooms = rooms;
            config.min_rooms = config.min_rooms.min(rooms);
        }
        if let Some(area) = self.max_area {
            if !(area.is_finite() && area > 0.0) {
                return Err(SimError::InvalidConfig {
                    field: "max_area",
                    value: area.to_string(),
                    reason: "must be a positive number of m²",
                });
            }
            config.max_area = area;
            config.min_area = config.min_area.min(area);
        }
        Ok(config)
    }

    /// Builds the scene: generates the house, or loads and places the file (with any loader
    /// warnings and the placement report).
    pub fn load(&self) -> Result<Loaded> {
        match self.house_seed()? {
            Some(seed) => {
                if let Some((field, value)) = self.placement.keys().into_iter().next() {
                    return Err(SimError::InvalidConfig {
                        field,
                        value,
                        reason: "applies to scene files, not to procedural houses",
                    });
                }
                Ok(Loaded {
                    scene: house::generate(seed, &self.house_config()?)?.scene,
                    warnings: Vec::new(),
                    placement: None,
                })
            }
            None => load_scene(
                Path::new(&self.scene),
                &LoadOptions {
                    placement: self.placement,
                },
            ),
        }
    }

    /// The simulator of this scene with `config`; loader warnings and the placement report
    /// (e.g. the tilt `floor: auto` removed) go to stderr.
    pub fn simulator(&self, config: SimConfig) -> Result<Simulator> {
        let loaded = self.load()?;
        for warning in &loaded.warnings {
            eprintln!("{warning}");
        }
        if let Some(report) = &loaded.placement {
            eprintln!("{report}");
        }
        Simulator::new(loaded.scene, config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::UpAxis;

    #[test]
    fn houses_take_their_seed_and_size_limits() {
        let mut spec = SceneSpec::new("house:3");
        spec.max_rooms = Some(2);
        spec.max_area = Some(40.0);
        assert_eq!(spec.house_seed().unwrap(), Some(3));
        let config = spec.house_config().unwrap();
        assert_eq!((config.max_rooms, config.max_area), (2, 40.0));
        assert!(config.min_rooms <= 2 && config.min_area <= 40.0);
        let built = spec.load().unwrap().scene;
        let direct = house::generate(3, &config).unwrap().scene;
        assert_eq!(built.triangles.len(), direct.triangles.len());
        assert_eq!(built.bounds(), direct.bounds());
    }

    #[test]
    fn bad_values_are_errors_that_name_the_field() {
        let message = |spec: SceneSpec| spec.load().unwrap_err().to_string();
        assert!(message(SceneSpec::new("house:x")).contains("scene = house:x"));
        let mut rooms = SceneSpec::new("house:1");
        rooms.max_rooms = Some(0);
        assert!(message(rooms).contains("max_rooms = 0"));
        let mut area = SceneSpec::new("house:1");
        area.max_area = Some(f64::NAN);
        assert!(message(area).contains("max_area = NaN"));
        let mut up = SceneSpec::new("house:1");
        up.placement.up_axis = Some(UpAxis::Z);
        assert!(message(up).contains("up_axis"));
        let mut floor = SceneSpec::new("house:1");
        floor.placement.floor = crate::Floor::Auto;
        assert!(message(floor).contains("floor = auto"));
        let mut transform = SceneSpec::new("house:1");
        transform.placement.transform = Some(crate::Transform {
            scale: Some(2.0),
            ..Default::default()
        });
        let m = message(transform);
        assert!(
            m.contains("transform = scale 2") && m.contains("scene files"),
            "{m}"
        );
        let missing = message(SceneSpec::new("/nonexistent/room.glb"));
        assert!(missing.contains("/nonexistent/room.glb"), "{missing}");
    }

    #[test]
    fn the_up_axis_reaches_the_file_loader() {
        // A vertical quad 2 m high in a z-up PLY; read as y-up, its height becomes depth (−y).
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wall.ply");
        let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
            property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
            0 0 0\n1 0 0\n1 0 2\n0 0 2\n4 0 1 2 3\n";
        std::fs::write(&path, ply).unwrap();
        let as_z = SceneSpec::new(path.to_str().unwrap());
        let mut as_y = as_z.clone();
        as_y.placement.up_axis = Some(UpAxis::Y);
        let bz = as_z.load().unwrap().scene.bounds().unwrap();
        let by = as_y.load().unwrap().scene.bounds().unwrap();
        assert_eq!((bz.min.z, bz.max.z), (0.0, 2.0));
        assert_eq!((by.min.y, by.max.y, by.max.z), (-2.0, 0.0, 0.0));
    }
}
