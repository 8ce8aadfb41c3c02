//! `activemap scene inspect FILE [KEY=VALUE ...]`: the placement a scene file gets, its
//! navigable floor and rooms, and a top-down PNG, without running an episode.

use std::path::{Path, PathBuf};

use activemap_sim::inspect::{DOOR_CLEARANCE, ROOM_CLEARANCE, inspect, room_colour};
use activemap_sim::{Placement, SceneSpec, SimConfig};
use anyhow::{Context as _, bail};

/// Options of `activemap scene inspect`.
#[derive(clap::Args)]
pub struct InspectArgs {
    /// Scene file (.glb, .gltf, .obj, .ply), or `house:SEED` for a procedural house.
    pub file: String,
    /// Placement keys as in the `sim` node's config, each KEY=VALUE with VALUE read as YAML:
    /// `up_axis=auto floor=auto`, `'transform={scale: 0.01, rotate_deg: [-34, 0, 0]}'`.
    #[arg(value_name = "KEY=VALUE")]
    pub keys: Vec<String>,
    /// Where to write the top-down view; default `<file name>.top.png` in the working
    /// directory.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Size of a pixel of the top-down view, metres.
    #[arg(long, default_value_t = 0.02)]
    pub metres_per_pixel: f64,
}

/// The placement of `keys` (`KEY=VALUE`, VALUE as YAML), checked like a node's config.
fn placement(keys: &[String]) -> anyhow::Result<Placement> {
    let mut map = serde_json::Map::new();
    for text in keys {
        let Some((key, value)) = text.split_once('=') else {
            bail!("`{text}`: expected KEY=VALUE (up_axis, transform or floor)");
        };
        let value = activemap_runtime::yaml::parse(value)
            .map_err(|e| anyhow::anyhow!("`{text}`: the value is not valid YAML: {}", e.message))?
            .to_json();
        if map.insert(key.trim().to_string(), value).is_some() {
            bail!("`{text}`: {key} is given twice");
        }
    }
    serde_json::from_value(serde_json::Value::Object(map))
        .context("placement keys (up_axis, transform, floor)")
}

/// Runs `activemap scene inspect`.
pub fn run(args: &InspectArgs) -> anyhow::Result<()> {
    let spec = SceneSpec {
        placement: placement(&args.keys)?,
        ..SceneSpec::new(args.file.clone())
    };
    let config = SimConfig::default();
    let found = inspect(&spec, &config).with_context(|| format!("inspecting {}", args.file))?;
    println!("scene: {}", args.file);
    for warning in &found.loaded.warnings {
        println!("{warning}");
    }
    match &found.loaded.placement {
        Some(report) => println!("{report}"),
        None if spec.house_seed()?.is_some() => println!("placement: a procedural house"),
        None => println!(
            "placement: {}: as the file is (the format's default up axis; no keys set)",
            args.file
        ),
    }
    println!("floor: z = {:.3} m", found.floor_z);
    let map = found.navigation.map();
    println!(
        "navigable floor: {:.2} m² ({} cm cells, robot radius {:.2} m)",
        map.area(),
        (100.0 * map.frame.cell_size).round(),
        found.navigation.shape().radius
    );
    let rooms = &found.rooms.rooms;
    let in_rooms: f64 = rooms.iter().map(|r| r.area).sum();
    println!(
        "rooms: {} ({:.2} m² of the navigable floor; rooms meet at necks of the free space: \
         openings narrower than about {:.1} m, doorways with under {DOOR_CLEARANCE} m of it)",
        rooms.len(),
        in_rooms,
        2.0 * ROOM_CLEARANCE
    );
    for (k, r) in rooms.iter().enumerate() {
        let [red, green, blue] = room_colour(k);
        println!(
            "  {}. {:.2} m² around ({:.2}, {:.2}), #{red:02x}{green:02x}{blue:02x} in the view",
            k + 1,
            r.area,
            r.centre.0,
            r.centre.1
        );
    }
    let png = args.png.clone().unwrap_or_else(|| default_png(&args.file));
    let (w, h) = found
        .write_top_down(&png, args.metres_per_pixel)
        .with_context(|| format!("writing the top-down view {}", png.display()))?;
    println!(
        "top-down view: {} ({w} × {h} px, x to the right, y up; cut {} m above the floor)",
        png.display(),
        activemap_sim::inspect::VIEW_CUT
    );
    Ok(())
}

/// `<file name>.top.png` in the working directory.
fn default_png(file: &str) -> PathBuf {
    let name = Path::new(file)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    PathBuf::from(format!("{name}.top.png"))
}
