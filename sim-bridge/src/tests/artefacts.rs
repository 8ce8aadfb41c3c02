//! Ignored drivers for development: the benchmark and a few saved frames.
//! Run: `cargo test -p activemap-sim --release -- --ignored --nocapture`.

use crate::house::{HouseConfig, generate};
use crate::render::RgbdFrame;
use crate::simulator::{Action, SimConfig, Simulator};
use std::path::Path;

/// Saves colour and a depth visualisation (near = bright, no reading = black) as PNGs.
fn save(frame: &RgbdFrame, dir: &Path, stem: &str) {
    let (w, h) = (frame.width(), frame.height());
    image::RgbImage::from_raw(w, h, frame.rgb.clone())
        .unwrap()
        .save(dir.join(format!("{stem}_rgb.png")))
        .unwrap();
    let max = frame.depth.iter().cloned().fold(0.0f32, f32::max).max(1e-3);
    let d: Vec<u8> = frame
        .depth
        .iter()
        .map(|&z| {
            if z > 0.0 {
                (255.0 * (1.0 - 0.85 * z / max)) as u8
            } else {
                0
            }
        })
        .collect();
    image::GrayImage::from_raw(w, h, d)
        .unwrap()
        .save(dir.join(format!("{stem}_depth.png")))
        .unwrap();
}

#[test]
#[ignore = "writes PNGs under /work/tgt/sim/frames (development aid)"]
fn save_rendered_frames() {
    // FRAMES_DIR picks the folder; by default a folder in the system's temp dir.
    let dir = std::env::var_os("FRAMES_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("activemap-frames"));
    let dir = dir.as_path();
    std::fs::create_dir_all(dir).unwrap();
    for seed in [1u64, 2] {
        let house = generate(seed, &HouseConfig::default()).unwrap();
        crate::export::write_glb(&house.scene, &dir.join(format!("house_seed{seed}.glb"))).unwrap();
        let mut sim = Simulator::new(house.scene, SimConfig::with_resolution(400, 400)).unwrap();
        save(&sim.render(), dir, &format!("house{seed}_start"));
        for i in 0..120 {
            sim.step(if i % 4 == 0 {
                Action::TurnLeft
            } else {
                Action::Forward
            });
        }
        save(&sim.render(), dir, &format!("house{seed}_walk"));
        // Top-down navigable map.
        let map = sim.navigation().map();
        let f = map.frame;
        let img = image::GrayImage::from_fn(f.width as u32, f.height as u32, |i, j| {
            let jj = f.height - 1 - j as usize;
            image::Luma([if map.is_navigable(i as usize, jj) {
                255
            } else {
                40
            }])
        });
        img.save(dir.join(format!("house{seed}_navigable.png")))
            .unwrap();
    }
    let data =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/scenes/simple_room.glb");
    if data.exists() {
        let opts = crate::load::LoadOptions::up_axis(crate::load::UpAxis::Z);
        let scene = crate::load::load_scene(&data, &opts).unwrap().scene;
        let mut sim = Simulator::new(scene, SimConfig::with_resolution(400, 400)).unwrap();
        sim.set_planar_pose(activemap_geometry::PlanarPose::new(-3.0, -2.0, 0.6))
            .unwrap();
        save(&sim.render(), dir, "simple_room");
    }
}

#[test]
#[ignore = "benchmark (development aid)"]
fn bench_sim() {
    for row in crate::bench::run(40).unwrap() {
        println!("{row}");
    }
}

#[test]
#[ignore = "timing of scene preparation (development aid)"]
fn time_preparation() {
    for seed in [1u64, 7] {
        let t = std::time::Instant::now();
        let house = generate(seed, &HouseConfig::default()).unwrap();
        let g = t.elapsed();
        let t = std::time::Instant::now();
        let sim = Simulator::new(house.scene, SimConfig::with_resolution(200, 200)).unwrap();
        println!(
            "seed {seed}: generate {g:?}, Simulator::new {:?}, {} triangles, navigable {:.1} m², rooms {}",
            t.elapsed(),
            sim.scene().triangles.len(),
            sim.navigation().map().area(),
            house.rooms.len()
        );
    }
}

#[test]
#[ignore = "prints the large homes' and offices' sizes and writes their navigable maps as PNGs (development aid)"]
fn describe_large_scenes() {
    use crate::house::{RoomKind, Style};
    let dir = std::env::temp_dir().join("activemap-large-scenes");
    std::fs::create_dir_all(&dir).unwrap();
    for style in [Style::Home, Style::Office] {
        for seed in 1..=6u64 {
            let t = std::time::Instant::now();
            let house = generate(seed, &HouseConfig::for_style(style)).unwrap();
            let g = t.elapsed();
            let area: f64 = house.rooms.iter().map(|r| r.area()).sum();
            let rooms = house
                .rooms
                .iter()
                .filter(|r| r.kind != RoomKind::Corridor)
                .count();
            let sim = Simulator::new(house.scene, SimConfig::with_resolution(96, 96)).unwrap();
            let map = sim.navigation().map();
            let f = map.frame;
            let pixels: Vec<u8> = (0..f.height)
                .rev()
                .flat_map(|j| (0..f.width).map(move |i| (i, j)))
                .map(|(i, j)| if map.is_navigable(i, j) { 255 } else { 0 })
                .collect();
            let name = format!("{}_{seed}", style.prefix());
            image::GrayImage::from_raw(f.width as u32, f.height as u32, pixels)
                .unwrap()
                .save(dir.join(format!("{name}.png")))
                .unwrap();
            println!(
                "{name}: {area:.0} m² in {rooms} rooms, {} doors, navigable {:.0} m², {} triangles, generated in {g:?}",
                house.doors.len(),
                map.area(),
                sim.scene().triangles.len()
            );
        }
    }
}
