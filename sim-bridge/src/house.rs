//! Seeded procedural houses: a rectangular footprint split recursively (BSP) into 3–8 rooms,
//! one door in every split wall (so every room connects to every other), textured floors,
//! walls and ceilings, and furniture against the walls and in the middle of large rooms.
//!
//! Two larger styles share the generator ([`Style`]): homes (250–420 m², 8–14 rooms) and
//! offices (350–600 m², 12–20 rooms). Their footprint opens with a double-height hall across
//! one end, then one or two corridors run its length between strips of rooms; every room that
//! touches a corridor or the hall gets its own door onto it, rooms split off deeper inside a
//! strip are entered through their neighbour. They exist so that a 2000-step episode does not
//! see everything (issue 36: the default houses saturate 2D coverage by step 430–730).
//!
//! The layout is computed in integer units of 5 cm and the textures with integer hashing and
//! f32 arithmetic (see [`crate::procedural_texture`]); only `+ − × ÷` and `sqrt` (all correctly
//! rounded in IEEE 754) touch floating point, so a seed gives the same house on every machine.
//! Lighting is baked into vertex colours (a fixed shade per face direction, darker near the
//! floor), since the renderer is unlit. After furnishing, the navigable map is checked and
//! furniture is removed until every room is reachable from the start for an agent of
//! [`HouseConfig::agent_radius`].

use crate::error::{Result, SimError};
use crate::navigation::{AgentShape, Navigation};
use crate::procedural_texture::{self, TextureKind};
use crate::scene::{Material, Scene, Triangle, Vertex};
use activemap_geometry::PlanarPose;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The layout grid unit, metres.
const UNIT: f64 = 0.05;

/// Generator settings.
#[derive(Debug, Clone, PartialEq)]
pub struct HouseConfig {
    /// Fewest rooms (≥ 1).
    pub min_rooms: u32,
    /// Most rooms.
    pub max_rooms: u32,
    /// Smallest footprint, m².
    pub min_area: f64,
    /// Largest footprint, m².
    pub max_area: f64,
    /// Shortest room side (wall centre to wall centre), metres.
    pub min_room_side: f64,
    /// Wall (and ceiling) height, metres.
    pub wall_height: f64,
    /// Wall thickness, metres.
    pub wall_thickness: f64,
    /// Door opening width, metres.
    pub door_width: f64,
    /// Door opening height, metres.
    pub door_height: f64,
    /// Place furniture.
    pub furniture: bool,
    /// Texture side in texels (power of two).
    pub texture_size: u32,
    /// World size covered by one texture tile on floors and walls, metres.
    pub texture_metres: f64,
    /// Radius of the agent for which every room must be reachable, metres.
    pub agent_radius: f64,
    /// Layout family: BSP house, or corridor-served home or office.
    pub style: Style,
    /// Corridor width between wall centre lines, metres (homes and offices).
    pub corridor_width: f64,
    /// Ceiling height of the hall (homes and offices), metres: more than one storey where it
    /// fits, so that the camera's upward view matters.
    pub hall_height: f64,
}

/// Layout family of a procedural scene (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// `house:<seed>`: a BSP split of a 50–150 m² footprint, one door per split wall.
    House,
    /// `home:<seed>`: a hall, one corridor and 8–14 rooms on 250–420 m².
    Home,
    /// `office:<seed>`: a lobby, one or two corridors and 12–20 rooms on 350–600 m².
    Office,
}

impl Style {
    /// The scene-name prefix of the style (`house`, `home`, `office`).
    pub fn prefix(self) -> &'static str {
        match self {
            Style::House => "house",
            Style::Home => "home",
            Style::Office => "office",
        }
    }

    /// The style named by a scene-name prefix.
    pub fn from_prefix(prefix: &str) -> Option<Style> {
        [Style::House, Style::Home, Style::Office]
            .into_iter()
            .find(|s| s.prefix() == prefix)
    }
}

impl Default for HouseConfig {
    fn default() -> Self {
        Self {
            min_rooms: 3,
            max_rooms: 8,
            min_area: 50.0,
            max_area: 150.0,
            min_room_side: 2.4,
            wall_height: 2.5,
            wall_thickness: 0.1,
            door_width: 0.9,
            door_height: 2.1,
            furniture: true,
            texture_size: 256,
            texture_metres: 2.0,
            agent_radius: activemap_geometry::RobotModel::default().radius_m,
            style: Style::House,
            corridor_width: 1.6,
            hall_height: 5.0,
        }
    }
}

impl HouseConfig {
    /// The settings of a style: [`HouseConfig::default`] for houses, the large presets for
    /// homes and offices.
    pub fn for_style(style: Style) -> Self {
        let base = Self::default();
        match style {
            Style::House => base,
            Style::Home => Self {
                min_rooms: 8,
                max_rooms: 14,
                min_area: 250.0,
                max_area: 420.0,
                min_room_side: 2.6,
                style,
                corridor_width: 1.5,
                hall_height: 5.0,
                ..base
            },
            Style::Office => Self {
                min_rooms: 12,
                max_rooms: 20,
                min_area: 350.0,
                max_area: 600.0,
                min_room_side: 2.8,
                wall_height: 2.7,
                style,
                corridor_width: 2.0,
                hall_height: 5.4,
                ..base
            },
        }
    }
}

/// What a room is for: corridors and halls are the hubs that every touching room opens onto.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RoomKind {
    /// A room (bedroom, office, kitchen…).
    Room,
    /// A corridor: no furniture.
    Corridor,
    /// The double-height hall or lobby of a home or office.
    Hall,
}

/// A room: the rectangle between its walls' centre lines.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Room {
    /// Lower-left corner (world x, y), metres.
    pub min: [f64; 2],
    /// Upper-right corner, metres.
    pub max: [f64; 2],
    /// What the room is for.
    pub kind: RoomKind,
}

impl Room {
    /// Floor area between the wall centre lines, m².
    pub fn area(&self) -> f64 {
        (self.max[0] - self.min[0]) * (self.max[1] - self.min[1])
    }
    /// Centre of the room.
    pub fn centre(&self) -> [f64; 2] {
        [
            0.5 * (self.min[0] + self.max[0]),
            0.5 * (self.min[1] + self.max[1]),
        ]
    }
}

/// A door opening on a wall centre line, from `a` to `b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Door {
    /// One end of the opening (world x, y).
    pub a: [f64; 2],
    /// The other end.
    pub b: [f64; 2],
}

/// A generated house.
#[derive(Debug, Clone)]
pub struct House {
    /// The mesh (floor at z = 0, `floor_z` and `start` set).
    pub scene: Scene,
    /// The rooms.
    pub rooms: Vec<Room>,
    /// The doors.
    pub doors: Vec<Door>,
    /// The start pose (also in `scene.start`).
    pub start: PlanarPose,
}

impl House {
    /// The room the start pose stands in (`None` only for a house without rooms).
    pub fn start_room(&self) -> Option<&Room> {
        let (x, y) = (self.start.x, self.start.y);
        self.rooms
            .iter()
            .find(|r| (r.min[0]..=r.max[0]).contains(&x) && (r.min[1]..=r.max[1]).contains(&y))
            .or(self.rooms.first())
    }
}

/// Integer rectangle in layout units: [x0, y0, x1, y1].
type Rect = [i64; 4];

#[derive(Debug, Clone)]
struct Node {
    rect: Rect,
    /// (axis 0 = wall at x = pos, 1 = wall at y = pos; pos; children)
    split: Option<(usize, i64, usize, usize)>,
}

/// A wall centre line: `axis` 0 = the line x = pos running along y, 1 = the line y = pos.
#[derive(Debug, Clone)]
struct WallLine {
    axis: usize,
    pos: i64,
    from: i64,
    to: i64,
    openings: Vec<(i64, i64)>,
}

fn units(m: f64) -> i64 {
    (m / UNIT).round() as i64
}

fn metres(u: i64) -> f64 {
    u as f64 * UNIT
}

/// Generates a house from `seed`.
pub fn generate(seed: u64, config: &HouseConfig) -> Result<House> {
    validate(config)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for _attempt in 0..200 {
        if let Some(h) = try_generate(seed, &mut rng, config)? {
            return Ok(h);
        }
    }
    Err(SimError::InvalidConfig {
        field: "house",
        value: format!("seed {seed}"),
        reason: "no valid layout found in 200 attempts; relax min_room_side or the area range",
    })
}

fn validate(c: &HouseConfig) -> Result<()> {
    let bad = |field, value: String, reason| {
        Err(SimError::InvalidConfig {
            field,
            value,
            reason,
        })
    };
    if c.min_rooms == 0 || c.min_rooms > c.max_rooms || c.max_rooms > 64 {
        return bad(
            "min_rooms/max_rooms",
            format!("{}..{}", c.min_rooms, c.max_rooms),
            "need 1 <= min <= max <= 64",
        );
    }
    if !(c.min_area > 0.0 && c.max_area >= c.min_area && c.max_area < 1.0e5) {
        return bad(
            "min_area/max_area",
            format!("{}..{}", c.min_area, c.max_area),
            "need 0 < min <= max",
        );
    }
    if !(c.wall_thickness > 0.0 && c.door_height < c.wall_height && c.door_height > 0.0) {
        return bad(
            "wall_thickness/door_height",
            format!("{}/{}", c.wall_thickness, c.door_height),
            "need thickness > 0 and 0 < door height < wall height",
        );
    }
    if !(c.door_width > 2.0 * c.agent_radius
        && c.min_room_side > c.door_width + 2.0 * c.wall_thickness)
    {
        return bad(
            "door_width",
            c.door_width.to_string(),
            "door must pass the agent and fit in a room side",
        );
    }
    if !(c.texture_size.is_power_of_two() && c.texture_size >= 16 && c.texture_metres > 0.0) {
        return bad(
            "texture_size",
            c.texture_size.to_string(),
            "need a power of two >= 16 and texture_metres > 0",
        );
    }
    if c.style != Style::House {
        if !(c.corridor_width >= c.door_width + 2.0 * c.wall_thickness + 0.2
            && c.corridor_width < c.min_room_side * 2.0)
        {
            return bad(
                "corridor_width",
                c.corridor_width.to_string(),
                "a corridor must hold a door (door width + 2 × (wall thickness + 0.1 m)) and stay narrower than two rooms",
            );
        }
        if !(c.hall_height >= c.wall_height && c.hall_height < 20.0) {
            return bad(
                "hall_height",
                c.hall_height.to_string(),
                "need wall height <= hall height < 20 m",
            );
        }
    }
    Ok(())
}

fn leaves(nodes: &[Node], i: usize, out: &mut Vec<usize>) {
    match nodes[i].split {
        Some((_, _, l, r)) => {
            leaves(nodes, l, out);
            leaves(nodes, r, out);
        }
        None => out.push(i),
    }
}

/// A floor plan: the split tree, its leaves (the rooms, by node index ascending) and what each
/// node is (only leaves' kinds matter).
struct Plan {
    nodes: Vec<Node>,
    rooms: Vec<usize>,
    kinds: Vec<RoomKind>,
}

/// Splits node `id` at `pos` on `axis` (0: the wall x = pos); returns the (lower, upper) children.
fn split(nodes: &mut Vec<Node>, id: usize, axis: usize, pos: i64) -> (usize, usize) {
    let r = nodes[id].rect;
    let (mut left, mut right) = (r, r);
    left[axis + 2] = pos;
    right[axis] = pos;
    nodes.push(Node {
        rect: left,
        split: None,
    });
    nodes.push(Node {
        rect: right,
        split: None,
    });
    let (li, ri) = (nodes.len() - 2, nodes.len() - 1);
    nodes[id].split = Some((axis, pos, li, ri));
    (li, ri)
}

/// Splits the largest splittable leaf of `leaves` along its longer side (at 35–65 %, no side
/// below `min_side`) until there are `target` leaves; `None` when no leaf can be split.
fn split_largest(
    rng: &mut ChaCha8Rng,
    nodes: &mut Vec<Node>,
    leaves: &mut Vec<usize>,
    target: usize,
    min_side: i64,
) -> Option<()> {
    while leaves.len() < target {
        let mut order: Vec<usize> = (0..leaves.len()).collect();
        let area_of = |r: &Rect| (r[2] - r[0]) * (r[3] - r[1]);
        order.sort_by_key(|&k| std::cmp::Reverse(area_of(&nodes[leaves[k]].rect)));
        let k = order.into_iter().find(|&k| {
            let r = nodes[leaves[k]].rect;
            (r[2] - r[0]).max(r[3] - r[1]) >= 2 * min_side
        })?;
        let id = leaves[k];
        let r = nodes[id].rect;
        let axis = if r[2] - r[0] >= r[3] - r[1] { 0 } else { 1 };
        let (a, b) = (r[axis], r[axis + 2]);
        let t = rng.random_range(0.35..0.65);
        let pos = (a + (metres(b - a) * t / UNIT).round() as i64).clamp(a + min_side, b - min_side);
        let (li, ri) = split(nodes, id, axis, pos);
        leaves[k] = li;
        leaves.push(ri);
    }
    Some(())
}

/// The house plan: a footprint of the drawn area and aspect split by [`split_largest`].
fn house_plan(rng: &mut ChaCha8Rng, c: &HouseConfig) -> Option<Plan> {
    let n_rooms = rng.random_range(c.min_rooms..=c.max_rooms) as usize;
    let min_side = units(c.min_room_side);
    let lo_area = c
        .min_area
        .max(n_rooms as f64 * c.min_room_side * c.min_room_side * 1.2)
        .min(c.max_area);
    let area = rng.random_range(lo_area..=c.max_area);
    let aspect = rng.random_range(1.0..1.7);
    let width = units((area * aspect).sqrt());
    let depth = units(area / metres(width));
    let mut nodes = vec![Node {
        rect: [0, 0, width, depth],
        split: None,
    }];
    let mut rooms = vec![0usize];
    split_largest(rng, &mut nodes, &mut rooms, n_rooms, min_side)?;
    rooms.sort_unstable();
    let kinds = vec![RoomKind::Room; nodes.len()];
    Some(Plan {
        nodes,
        rooms,
        kinds,
    })
}

/// The plan of a home or office: a hall 5–7.5 m wide across the west end of the footprint, then
/// strips of rooms along x with a corridor between each pair (two corridors when the footprint
/// is at least 17 m deep), the strips split by [`split_largest`] until the drawn room count
/// (the hall included, corridors not) is reached.
fn corridor_plan(rng: &mut ChaCha8Rng, c: &HouseConfig) -> Option<Plan> {
    let n_rooms = rng.random_range(c.min_rooms..=c.max_rooms) as usize;
    let min_side = units(c.min_room_side);
    let area = rng.random_range(c.min_area..=c.max_area);
    let aspect = rng.random_range(1.4..2.4);
    let width = units((area * aspect).sqrt());
    let depth = units(area / metres(width));
    let cw = units(c.corridor_width);
    let corridors: i64 = if metres(depth) >= 17.0 { 2 } else { 1 };
    let hall_w = units(rng.random_range(5.0..7.5));
    if depth - corridors * cw < (corridors + 1) * min_side || width - hall_w < 2 * min_side {
        return None;
    }
    let mut nodes = vec![Node {
        rect: [0, 0, width, depth],
        split: None,
    }];
    let (hall, mut rest) = split(&mut nodes, 0, 0, hall_w);
    let mut strips = Vec::new();
    let mut corridor_ids = Vec::new();
    for k in 0..corridors {
        let r = nodes[rest].rect;
        let strips_left = corridors + 1 - k;
        let room_depth = (r[3] - r[1]) - (corridors - k) * cw;
        let share = (room_depth as f64 / strips_left as f64 * rng.random_range(0.85..1.15)) as i64;
        let d = share.clamp(min_side, room_depth - (strips_left - 1) * min_side);
        let (strip, remainder) = split(&mut nodes, rest, 1, r[1] + d);
        let (corridor, next) = split(&mut nodes, remainder, 1, r[1] + d + cw);
        strips.push(strip);
        corridor_ids.push(corridor);
        rest = next;
    }
    strips.push(rest);
    split_largest(
        rng,
        &mut nodes,
        &mut strips,
        n_rooms.saturating_sub(1),
        min_side,
    )?;
    let mut kinds = vec![RoomKind::Room; nodes.len()];
    kinds[hall] = RoomKind::Hall;
    for &id in &corridor_ids {
        kinds[id] = RoomKind::Corridor;
    }
    let mut rooms: Vec<usize> = strips;
    rooms.push(hall);
    rooms.extend(corridor_ids);
    rooms.sort_unstable();
    Some(Plan {
        nodes,
        rooms,
        kinds,
    })
}

fn try_generate(seed: u64, rng: &mut ChaCha8Rng, c: &HouseConfig) -> Result<Option<House>> {
    let plan = match c.style {
        Style::House => house_plan(rng, c),
        Style::Home | Style::Office => corridor_plan(rng, c),
    };
    let Some(Plan {
        nodes,
        rooms,
        kinds,
    }) = plan
    else {
        return Ok(None);
    };

    // One door per split wall, between the pair of rooms sharing the longest stretch of it.
    let t = units(c.wall_thickness);
    let door = units(c.door_width);
    let margin = t + 2;
    let mut walls = Vec::new();
    let root = nodes[0].rect;
    for (axis, pos) in [(0, root[0]), (0, root[2]), (1, root[1]), (1, root[3])] {
        let other = 1 - axis;
        walls.push(WallLine {
            axis,
            pos,
            from: root[other],
            to: root[other + 2],
            openings: vec![],
        });
    }
    for i in 0..nodes.len() {
        let Some((axis, pos, l, r)) = nodes[i].split else {
            continue;
        };
        let other = 1 - axis;
        let (mut ls, mut rs) = (Vec::new(), Vec::new());
        leaves(&nodes, l, &mut ls);
        leaves(&nodes, r, &mut rs);
        // A room touching a corridor or the hall gets its own door onto it; otherwise the
        // wall gets one door, between the pair of rooms sharing its longest stretch.
        let mut best: Option<(i64, i64)> = None;
        let mut hub_stretches = Vec::new();
        for &a in ls.iter().filter(|&&a| nodes[a].rect[axis + 2] == pos) {
            for &b in rs.iter().filter(|&&b| nodes[b].rect[axis] == pos) {
                let (ra, rb) = (nodes[a].rect, nodes[b].rect);
                let lo = ra[other].max(rb[other]);
                let hi = ra[other + 2].min(rb[other + 2]);
                if kinds[a] != RoomKind::Room || kinds[b] != RoomKind::Room {
                    if hi - lo >= door + 2 * margin {
                        hub_stretches.push((lo, hi));
                    }
                } else if best.is_none_or(|(bl, bh)| hi - lo > bh - bl) {
                    best = Some((lo, hi));
                }
            }
        }
        let openings = if hub_stretches.is_empty() {
            let Some((lo, hi)) = best else {
                return Ok(None);
            };
            if hi - lo < door + 2 * margin {
                return Ok(None);
            }
            let start = rng.random_range(lo + margin..=hi - margin - door);
            vec![(start, start + door)]
        } else {
            hub_stretches.sort_unstable();
            hub_stretches
                .into_iter()
                .map(|(lo, hi)| {
                    let start = rng.random_range(lo + margin..=hi - margin - door);
                    (start, start + door)
                })
                .collect()
        };
        let rect = nodes[i].rect;
        walls.push(WallLine {
            axis,
            pos,
            from: rect[other],
            to: rect[other + 2],
            openings,
        });
    }

    let room_rects: Vec<Rect> = rooms.iter().map(|&i| nodes[i].rect).collect();
    let room_kinds: Vec<RoomKind> = rooms.iter().map(|&i| kinds[i]).collect();
    let heights: Vec<f64> = room_kinds
        .iter()
        .map(|&k| {
            if k == RoomKind::Hall {
                c.hall_height
            } else {
                c.wall_height
            }
        })
        .collect();
    let mut builder = Builder::new(c, seed);
    let floor_materials: Vec<u32> = (0..room_rects.len())
        .map(|_| {
            let kind = [
                TextureKind::WoodPlanks,
                TextureKind::Tiles,
                TextureKind::Carpet,
            ][rng.random_range(0..3)];
            builder.material(kind, rng.random())
        })
        .collect();
    let wall_materials: Vec<u32> = (0..room_rects.len())
        .map(|_| {
            let kind = [TextureKind::Plaster, TextureKind::Wallpaper][rng.random_range(0..2)];
            builder.material(kind, rng.random())
        })
        .collect();
    let ceiling = builder.material(TextureKind::Ceiling, rng.random());
    let frame = builder.material(TextureKind::WoodPlanks, rng.random());
    let furniture_materials = [
        builder.material(TextureKind::WoodPlanks, rng.random()),
        builder.material(TextureKind::Fabric, rng.random()),
        builder.material(TextureKind::Fabric, rng.random()),
    ];

    for (k, r) in room_rects.iter().enumerate() {
        let (x0, y0, x1, y1) = (metres(r[0]), metres(r[1]), metres(r[2]), metres(r[3]));
        builder.horizontal([x0, y0, x1, y1], 0.0, true, floor_materials[k]);
        builder.horizontal([x0, y0, x1, y1], heights[k], false, ceiling);
    }
    for w in &walls {
        builder.wall(w, &room_rects, &heights, &wall_materials, frame);
    }

    let room_list: Vec<Room> = room_rects
        .iter()
        .zip(&room_kinds)
        .map(|(r, &kind)| Room {
            min: [metres(r[0]), metres(r[1])],
            max: [metres(r[2]), metres(r[3])],
            kind,
        })
        .collect();
    let doors: Vec<Door> = walls
        .iter()
        .flat_map(|w| {
            w.openings.iter().map(move |&(a, b)| {
                let p = |s: i64| {
                    if w.axis == 0 {
                        [metres(w.pos), metres(s)]
                    } else {
                        [metres(s), metres(w.pos)]
                    }
                };
                Door { a: p(a), b: p(b) }
            })
        })
        .collect();

    // Furniture, then remove pieces until every room is reachable from the start.
    let structure = builder.scene.clone();
    let mut pieces: Vec<(usize, Vec<Box3>, u32)> = Vec::new();
    if c.furniture {
        for (k, room) in room_list.iter().enumerate() {
            if room.kind == RoomKind::Corridor {
                continue;
            }
            place_furniture(rng, c, k, room, &doors, &furniture_materials, &mut pieces);
        }
    }
    let shape = AgentShape {
        radius: c.agent_radius,
        ..AgentShape::default()
    };
    loop {
        let mut b = Builder {
            scene: structure.clone(),
            config: c.clone(),
        };
        for (_, boxes, material) in &pieces {
            for bx in boxes {
                b.cuboid(bx, *material);
            }
        }
        let mut scene = b.scene;
        scene.floor_z = Some(0.0);
        let nav = Navigation::build(&scene, 0.0, shape, 0.05)?;
        match check_reachability(&nav, &room_list) {
            Ok(start) => {
                scene.start = Some(start);
                return Ok(Some(House {
                    scene,
                    rooms: room_list,
                    doors,
                    start,
                }));
            }
            Err(unreached) => {
                // Drop the last piece in an unreachable room (or any piece, if none is there).
                let idx = pieces
                    .iter()
                    .rposition(|p| p.0 == unreached)
                    .or(pieces.len().checked_sub(1));
                match idx {
                    Some(i) => {
                        pieces.remove(i);
                    }
                    None => return Ok(None),
                }
            }
        }
    }
}

/// The start pose (nearest reachable navigable cell to the centre of room 0) when every room
/// is reachable from it, else the index of a room that is not.
fn check_reachability(nav: &Navigation, rooms: &[Room]) -> std::result::Result<PlanarPose, usize> {
    let map = nav.map();
    let f = map.frame;
    let (label, sizes) = map.components();
    if sizes.is_empty() {
        return Err(0);
    }
    let cells_in = |room: &Room| {
        let mut v = Vec::new();
        for j in 0..f.height {
            for i in 0..f.width {
                let (x, y) = f.centre(i, j);
                if x > room.min[0]
                    && x < room.max[0]
                    && y > room.min[1]
                    && y < room.max[1]
                    && map.is_navigable(i, j)
                {
                    v.push((i, j));
                }
            }
        }
        v
    };
    let first = cells_in(&rooms[0]);
    let c0 = rooms[0].centre();
    let Some(&(si, sj)) = first.iter().min_by(|a, b| {
        let d = |&(i, j): &(usize, usize)| {
            let (x, y) = f.centre(i, j);
            (x - c0[0]) * (x - c0[0]) + (y - c0[1]) * (y - c0[1])
        };
        d(a).total_cmp(&d(b))
    }) else {
        return Err(0);
    };
    let start_label = label[sj * f.width + si];
    for (k, room) in rooms.iter().enumerate().skip(1) {
        if !cells_in(room)
            .iter()
            .any(|&(i, j)| label[j * f.width + i] == start_label)
        {
            return Err(k);
        }
    }
    let (x, y) = f.centre(si, sj);
    Ok(PlanarPose::new(x, y, 0.0))
}

/// An axis-aligned box [x0, y0, z0, x1, y1, z1], metres.
type Box3 = [f64; 6];

fn overlaps(a: &Box3, b: &Box3, gap: f64) -> bool {
    a[0] < b[3] + gap && b[0] < a[3] + gap && a[1] < b[4] + gap && b[1] < a[4] + gap
}

fn place_furniture(
    rng: &mut ChaCha8Rng,
    c: &HouseConfig,
    room_index: usize,
    room: &Room,
    doors: &[Door],
    materials: &[u32; 3],
    pieces: &mut Vec<(usize, Vec<Box3>, u32)>,
) {
    let half = 0.5 * c.wall_thickness;
    let inner = [
        room.min[0] + half,
        room.min[1] + half,
        room.max[0] - half,
        room.max[1] - half,
    ];
    // Keep-out zones: 1 m either side of every door.
    let keep_out: Vec<Box3> = doors
        .iter()
        .map(|d| {
            let (x0, x1) = (d.a[0].min(d.b[0]), d.a[0].max(d.b[0]));
            let (y0, y1) = (d.a[1].min(d.b[1]), d.a[1].max(d.b[1]));
            [x0 - 1.0, y0 - 1.0, 0.0, x1 + 1.0, y1 + 1.0, 0.0]
        })
        .collect();
    let count = rng.random_range(1..=4u32);
    let mut placed: Vec<Box3> = Vec::new();
    for _ in 0..count {
        // (length along the wall, depth, height, material, is a table)
        let kinds: &[(f64, f64, f64, usize, bool)] = match c.style {
            Style::House | Style::Home => &[
                (2.0, 1.6, 0.5, 1, false),  // bed
                (1.9, 0.85, 0.8, 2, false), // sofa
                (1.0, 0.5, 1.9, 0, false),  // wardrobe
                (0.9, 0.35, 2.0, 0, false), // shelf
                (1.2, 0.6, 0.75, 0, true),  // desk
                (0.5, 0.5, 0.45, 2, false), // stool
            ],
            Style::Office => &[
                (1.6, 0.8, 0.75, 0, true),  // desk
                (1.6, 0.8, 0.75, 0, true),  // desk
                (1.2, 0.5, 1.3, 0, false),  // filing cabinet
                (0.9, 0.4, 2.0, 0, false),  // bookcase
                (2.0, 0.9, 0.85, 2, false), // sofa
                (0.8, 0.8, 1.1, 1, false),  // printer cabinet
            ],
        };
        let (len, dep, height, mat, table) = kinds[rng.random_range(0..kinds.len())];
        for _try in 0..8 {
            let side = rng.random_range(0..4u32);
            let along_axis = if side < 2 { 0 } else { 1 };
            let (lo, hi) = (inner[along_axis], inner[along_axis + 2]);
            if hi - lo < len + 0.1 {
                continue;
            }
            let s = lo + rng.random_range(0.0..1.0) * (hi - lo - len);
            let bx: Box3 = match side {
                0 => [s, inner[1], 0.0, s + len, inner[1] + dep, height],
                1 => [s, inner[3] - dep, 0.0, s + len, inner[3], height],
                2 => [inner[0], s, 0.0, inner[0] + dep, s + len, height],
                _ => [inner[2] - dep, s, 0.0, inner[2], s + len, height],
            };
            if placed.iter().any(|p| overlaps(p, &bx, 0.3))
                || keep_out.iter().any(|k| overlaps(k, &bx, 0.0))
            {
                continue;
            }
            placed.push(bx);
            let boxes = if table { table_boxes(&bx) } else { vec![bx] };
            pieces.push((room_index, boxes, materials[mat]));
            break;
        }
    }
    // A table in the middle of large rooms.
    let (w, d) = (inner[2] - inner[0], inner[3] - inner[1]);
    if w > 3.5 && d > 3.5 && rng.random_range(0.0..1.0) < 0.7 {
        let cx = inner[0] + w * rng.random_range(0.4..0.6);
        let cy = inner[1] + d * rng.random_range(0.4..0.6);
        let bx = [cx - 0.6, cy - 0.4, 0.0, cx + 0.6, cy + 0.4, 0.74];
        if !placed.iter().any(|p| overlaps(p, &bx, 0.6))
            && !keep_out.iter().any(|k| overlaps(k, &bx, 0.0))
        {
            pieces.push((room_index, table_boxes(&bx), materials[0]));
        }
    }
}

/// A table: a 4 cm top and four 5 cm legs inside the box `b`.
fn table_boxes(b: &Box3) -> Vec<Box3> {
    let (top, leg) = (0.04, 0.05);
    let mut v = vec![[b[0], b[1], b[5] - top, b[3], b[4], b[5]]];
    for (x, y) in [
        (b[0], b[1]),
        (b[3] - leg, b[1]),
        (b[0], b[4] - leg),
        (b[3] - leg, b[4] - leg),
    ] {
        v.push([x, y, 0.0, x + leg, y + leg, b[5] - top]);
    }
    v
}

/// Baked shade of a face by its outward normal (axis, sign).
fn face_shade(axis: usize, positive: bool) -> f32 {
    match (axis, positive) {
        (2, true) => 1.0,
        (2, false) => 0.8,
        (0, true) => 0.92,
        (0, false) => 0.84,
        (1, true) => 0.78,
        _ => 0.72,
    }
}

struct Builder {
    scene: Scene,
    config: HouseConfig,
}

impl Builder {
    fn new(c: &HouseConfig, seed: u64) -> Self {
        Builder {
            scene: Scene {
                name: format!("procedural {} seed {seed}", c.style.prefix()),
                ..Scene::default()
            },
            config: c.clone(),
        }
    }

    fn material(&mut self, kind: TextureKind, tex_seed: u32) -> u32 {
        let tex = procedural_texture::generate(kind, self.config.texture_size, tex_seed);
        self.scene.textures.push(tex);
        self.scene.materials.push(Material {
            name: format!("{kind:?}"),
            base_color: [1.0; 3],
            texture: Some((self.scene.textures.len() - 1) as u32),
        });
        (self.scene.materials.len() - 1) as u32
    }

    /// A quad with corners counter-clockwise seen from the front; `uv` in metres (scaled by
    /// the texture tile size); per-corner shade.
    fn quad(&mut self, p: [[f64; 3]; 4], uv: [[f64; 2]; 4], shade: [f32; 4], material: u32) {
        let base = self.scene.vertices.len() as u32;
        let tile = self.config.texture_metres;
        for k in 0..4 {
            self.scene.vertices.push(Vertex {
                position: p[k].map(|c| c as f32),
                uv: [(uv[k][0] / tile) as f32, (uv[k][1] / tile) as f32],
                color: [shade[k]; 3],
            });
        }
        for tri in [[0, 1, 2], [0, 2, 3]] {
            self.scene.triangles.push(Triangle {
                vertices: tri.map(|i| base + i),
                material,
            });
        }
    }

    /// Vertex shade of a vertical face at height z (darker near the floor).
    fn height_shade(&self, base: f32, z: f64) -> f32 {
        base * (0.8 + 0.2 * (z / self.config.wall_height) as f32)
    }

    /// A horizontal rectangle at height z facing up or down.
    fn horizontal(&mut self, r: [f64; 4], z: f64, up: bool, material: u32) {
        let s = face_shade(2, up);
        let (p, uv) = (
            [
                [r[0], r[1], z],
                [r[2], r[1], z],
                [r[2], r[3], z],
                [r[0], r[3], z],
            ],
            [[r[0], -r[1]], [r[2], -r[1]], [r[2], -r[3]], [r[0], -r[3]]],
        );
        if up {
            self.quad(p, uv, [s; 4], material);
        } else {
            self.quad(
                [p[0], p[3], p[2], p[1]],
                [uv[0], uv[3], uv[2], uv[1]],
                [s; 4],
                material,
            );
        }
    }

    /// A vertical rectangle on the plane `axis` = `at`, spanning `along` on the other axis and
    /// heights `z`, facing the positive or negative side; u runs along the wall, v down from
    /// the ceiling.
    fn vertical(
        &mut self,
        axis: usize,
        at: f64,
        along: [f64; 2],
        z: [f64; 2],
        positive: bool,
        material: u32,
    ) {
        let pt = |s: f64, h: f64| if axis == 0 { [at, s, h] } else { [s, at, h] };
        let (a, b) = (along[0], along[1]);
        let top = self.config.wall_height;
        let p = [pt(a, z[0]), pt(b, z[0]), pt(b, z[1]), pt(a, z[1])];
        let uv = [
            [a, top - z[0]],
            [b, top - z[0]],
            [b, top - z[1]],
            [a, top - z[1]],
        ];
        let s = face_shade(axis, positive);
        let shade = [
            self.height_shade(s, z[0]),
            self.height_shade(s, z[0]),
            self.height_shade(s, z[1]),
            self.height_shade(s, z[1]),
        ];
        // Counter-clockwise seen from the side the face looks at.
        let flip = (axis == 0) != positive;
        if flip {
            self.quad(
                [p[1], p[0], p[3], p[2]],
                [uv[1], uv[0], uv[3], uv[2]],
                [shade[1], shade[0], shade[3], shade[2]],
                material,
            );
        } else {
            self.quad(p, uv, shade, material);
        }
    }

    /// The faces of one wall line: per room on each side, the wall face minus door openings
    /// plus the lintels above them; jambs and lintel undersides once per opening.
    fn wall(
        &mut self,
        w: &WallLine,
        rooms: &[Rect],
        heights: &[f64],
        wall_materials: &[u32],
        frame: u32,
    ) {
        let c = self.config.clone();
        let half = 0.5 * c.wall_thickness;
        let other = 1 - w.axis;
        let pos = metres(w.pos);
        for (k, r) in rooms.iter().enumerate() {
            let side = if r[w.axis + 2] == w.pos {
                false // room lies on the negative side; its face looks towards −axis
            } else if r[w.axis] == w.pos {
                true
            } else {
                continue;
            };
            let lo = r[other].max(w.from);
            let hi = r[other + 2].min(w.to);
            if hi <= lo {
                continue;
            }
            let at = if side { pos + half } else { pos - half };
            // Each face rises to its own room's ceiling (the shading and texture rows too).
            let top = heights[k];
            self.config.wall_height = top;
            let mut cursor = lo;
            let mut openings: Vec<(i64, i64)> = w
                .openings
                .iter()
                .filter(|o| o.1 > lo && o.0 < hi)
                .copied()
                .collect();
            openings.sort_unstable();
            for (a, b) in openings {
                if a > cursor {
                    self.vertical(
                        w.axis,
                        at,
                        [metres(cursor), metres(a)],
                        [0.0, top],
                        side,
                        wall_materials[k],
                    );
                }
                self.vertical(
                    w.axis,
                    at,
                    [metres(a.max(lo)), metres(b.min(hi))],
                    [c.door_height, top],
                    side,
                    wall_materials[k],
                );
                cursor = b;
            }
            if cursor < hi {
                self.vertical(
                    w.axis,
                    at,
                    [metres(cursor), metres(hi)],
                    [0.0, top],
                    side,
                    wall_materials[k],
                );
            }
        }
        self.config.wall_height = c.wall_height;
        for &(a, b) in &w.openings {
            let (a, b) = (metres(a), metres(b));
            // Jambs: faces across the wall thickness at both ends of the opening.
            self.vertical(
                other,
                a,
                [pos - half, pos + half],
                [0.0, c.door_height],
                true,
                frame,
            );
            self.vertical(
                other,
                b,
                [pos - half, pos + half],
                [0.0, c.door_height],
                false,
                frame,
            );
            let r = if w.axis == 0 {
                [pos - half, a, pos + half, b]
            } else {
                [a, pos - half, b, pos + half]
            };
            self.horizontal(r, c.door_height, false, frame);
        }
    }

    /// A box without its bottom face.
    fn cuboid(&mut self, b: &Box3, material: u32) {
        self.horizontal([b[0], b[1], b[3], b[4]], b[5], true, material);
        let saved = self.config.wall_height;
        // Furniture shading darkens towards the floor relative to its own height.
        self.config.wall_height = b[5].max(0.5);
        self.vertical(0, b[0], [b[1], b[4]], [b[2], b[5]], false, material);
        self.vertical(0, b[3], [b[1], b[4]], [b[2], b[5]], true, material);
        self.vertical(1, b[1], [b[0], b[3]], [b[2], b[5]], false, material);
        self.vertical(1, b[4], [b[0], b[3]], [b[2], b[5]], true, material);
        self.config.wall_height = saved;
    }
}
