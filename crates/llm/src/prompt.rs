//! The prompt (SPEC §7): the paper's appendix text, system and user, with the total steps, the
//! current step and the number of candidates filled in. The sentence about the yellow diamond
//! (the last chosen frontier) is there only once a frontier was chosen before. The `text`
//! variant, for models without vision, keeps the task and the reply format and lists each
//! candidate's id, position, size and path distance instead of describing an image.
//! `json_first` is the paper's image prompt asking for the JSON object before the reasoning,
//! so that a reply cut by the token limit still holds the answer; `text_compact` is a short
//! text prompt for small models (the candidate list, the JSON first, a one-sentence reason).
//! [`follow_up_turn`] is the user turn that asks only for the JSON after a cut reply.

use crate::config::PromptStyle;

/// A candidate frontier as offered to the model; its index in the list is its number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Centroid of the region, world metres (x, y).
    pub centroid: [f64; 2],
    /// Where its number is drawn: the region's frontier cell nearest the centroid.
    pub label_at: [f64; 2],
    /// Region size, cells.
    pub size_cells: u32,
    /// Region size, square metres (cells × cell area).
    pub area_m2: f64,
    /// Path length from the robot to the region's approach cell, metres.
    pub path_distance_m: f64,
}

/// What the prompt says about the episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PromptFacts<'a> {
    /// `<TOTAL_STEPS>`.
    pub total_steps: u64,
    /// `<STEP_ID>`.
    pub step: u64,
    /// The candidates (`<NUM_FRAME>` = their number).
    pub candidates: &'a [Candidate],
    /// True once a frontier was chosen before (the yellow diamond is drawn).
    pub has_last_choice: bool,
    /// The robot's estimated position and heading (x, y metres, yaw radians), for the text
    /// variant.
    pub robot: [f64; 3],
    /// The last chosen frontier's position, for the text variant.
    pub last_choice: Option<[f64; 2]>,
}

/// The two messages of a query.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Prompt {
    /// The system message (the release puts the whole instruction there).
    pub system: String,
    /// The user message text (the image, if any, travels beside it).
    pub user: String,
}

/// The reply format and the closing lines, shared by both variants (the paper's example).
const REPLY_FORMAT: &str = "Please provide a detailed exploration plan and select an exploration target with reasons in the JSON format as shown below.\n\n\n```\n{\n\"target\": 2, \"reason\": \"The target is located at an unvisited region of the image and seems to be an unvisited bedroom\"\n}\n```\nDo not cut off the JSON and generate the full JSON.";

/// The reply format of `json_first`: the paper's example, asked for first.
const REPLY_FORMAT_JSON_FIRST: &str = "Start your reply with the exploration target and its reason in the JSON format shown below, and only after the JSON give a short exploration plan.\n\n\n```\n{\n\"target\": 2, \"reason\": \"The target is located at an unvisited region of the image and seems to be an unvisited bedroom\"\n}\n```\nThe JSON object must come first and be complete.";

/// The prompt of one query.
pub fn build(style: PromptStyle, facts: &PromptFacts<'_>) -> Prompt {
    match style {
        PromptStyle::Image => image_prompt(facts, false),
        PromptStyle::JsonFirst => image_prompt(facts, true),
        PromptStyle::Text => text_prompt(facts),
        PromptStyle::TextCompact => compact_prompt(facts),
    }
}

/// The follow-up user turn after a reply cut off or without the JSON answer, for a choice
/// among `candidates` candidates.
pub fn follow_up_turn(candidates: usize) -> String {
    format!(
        "Your reply was cut off or did not contain the JSON answer. Reply now with only the JSON object of your choice, nothing else: {{\"target\": <a candidate number from 0 to {}, or -1 to refine the map>, \"reason\": \"<one short sentence>\"}}",
        candidates.saturating_sub(1)
    )
}

fn image_prompt(f: &PromptFacts<'_>, json_first: bool) -> Prompt {
    let n = f.candidates.len();
    let mut s = String::new();
    s += "You are an AI assistant that can analyze images and plan a long-term goal for the exploration task of a ground robot.\n";
    s += "You will be given a bird-eye view image of a scene.\n";
    s += "The goal is to plan a long-term exploration mission for a robot to traverse the area.\n";
    s += "The robot's task is to explore the terrain efficiently, identifying important areas, potential obstacles, and unvisited areas.\n";
    s += "Please analyze the image and select a long-term goal from the candidates for the robot to explore the area.\n";
    s += "Empty space doesn't always mean they are unvisited regions, sometimes it's just outside the floor plan of this scene.\n";
    s += &format!(
        "We are allowed to explore a total of {} steps and this is step {}.\n",
        f.total_steps, f.step
    );
    s += "Therefore, it's better to select a space that is close to the visited regions but still unvisited and not behind the walls.\n";
    s += "The current location of the robot is marked with the blue star(*) marker.\n";
    if f.has_last_choice {
        s += "The last frontier you selected is marked with a yellow diamond shape.\n";
    }
    s += "The visited path is painted as green lines in the image.\n";
    s += "Note that you don't have to select the closest point to the robot, but the point that is most likely to be unvisited and important to explore.\n";
    s += &format!("As you can see, there are {n} candidate points to select from.\n");
    s += &format!(
        "They are numbered from 0 to {} in red color.\n",
        n.saturating_sub(1)
    );
    s += "If you find all the goals are not necessary to explore and we should instead focus on improving existing reconstruction, please give -1 in the `target` entry of the JSON.\n";
    s += if json_first {
        REPLY_FORMAT_JSON_FIRST
    } else {
        REPLY_FORMAT
    };
    let order = if json_first {
        "provide an exploration target in the specified JSON format first and then the exploration plan"
    } else {
        "provide the exploration plan first and then an exploration target in the specified JSON format"
    };
    Prompt {
        system: s,
        user: format!(
            "I have a bird-eye view image of a scene. The goal is to plan a long-term exploration mission for a robot to traverse the area. Please analyze the attached image and {order}."
        ),
    }
}

fn compact_prompt(f: &PromptFacts<'_>) -> Prompt {
    let n = f.candidates.len();
    let mut s = String::new();
    s += "You choose where a ground robot exploring an indoor scene goes next.\n";
    s += "Pick one candidate frontier (a boundary between mapped free space and unmapped space). Large frontiers close to the robot usually open onto unvisited rooms; small ones are often gaps along walls.\n";
    s += &format!(
        "Answer with one JSON object first, then nothing else: {{\"target\": <candidate number from 0 to {}>, \"reason\": \"<one short sentence>\"}}. Use -1 as the target only to improve the existing map instead of exploring.",
        n.saturating_sub(1)
    );
    let [x, y, yaw] = f.robot.map(|v| v + 0.0);
    let mut u = format!("Step {} of {}. ", f.step, f.total_steps);
    u += &format!(
        "Robot at x = {x:.2} m, y = {y:.2} m, heading {:.0} degrees.\n",
        yaw.to_degrees()
    );
    if let Some([lx, ly]) = f.last_choice {
        u += &format!("Last chosen frontier at x = {lx:.2} m, y = {ly:.2} m.\n");
    }
    u += "Candidates (number: position, size, path distance):\n";
    for (i, c) in f.candidates.iter().enumerate() {
        u += &format!(
            "{i}: x = {:.2} m, y = {:.2} m; {:.2} m²; {:.1} m\n",
            c.centroid[0], c.centroid[1], c.area_m2, c.path_distance_m
        );
    }
    u += "The JSON object:";
    Prompt { system: s, user: u }
}

fn text_prompt(f: &PromptFacts<'_>) -> Prompt {
    let n = f.candidates.len();
    let mut s = String::new();
    s += "You are an AI assistant that can analyze a map description and plan a long-term goal for the exploration task of a ground robot.\n";
    s += "You will be given a list of candidate frontiers (boundaries between mapped free space and unmapped space) of an indoor scene.\n";
    s += "The goal is to plan a long-term exploration mission for a robot to traverse the area.\n";
    s += "The robot's task is to explore the terrain efficiently, identifying important areas, potential obstacles, and unvisited areas.\n";
    s += "Please analyze the list and select a long-term goal from the candidates for the robot to explore the area.\n";
    s += &format!(
        "We are allowed to explore a total of {} steps and this is step {}.\n",
        f.total_steps, f.step
    );
    s += "Therefore, it's better to select a space that is close to the visited regions but still unvisited and not behind the walls.\n";
    s += "Large frontiers usually open onto unvisited rooms; small ones are often gaps along walls.\n";
    s += &format!(
        "There are {n} candidate points to select from, numbered from 0 to {}.\n",
        n.saturating_sub(1)
    );
    s += "If you find all the goals are not necessary to explore and we should instead focus on improving existing reconstruction, please give -1 in the `target` entry of the JSON.\n";
    s += REPLY_FORMAT;
    // `+ 0.0` turns −0.0 into 0.0, so that no "-0.00" reaches the model.
    let [x, y, yaw] = f.robot.map(|v| v + 0.0);
    let mut u = String::new();
    u += "I have a map of a scene. The goal is to plan a long-term exploration mission for a robot to traverse the area.\n";
    u += &format!(
        "The robot is at x = {x:.2} m, y = {y:.2} m, heading {:.0} degrees.\n",
        yaw.to_degrees()
    );
    if let Some([lx, ly]) = f.last_choice {
        u += &format!("The last frontier you selected was at x = {lx:.2} m, y = {ly:.2} m.\n");
    }
    u += "The candidate frontiers:\n";
    for (i, c) in f.candidates.iter().enumerate() {
        u += &format!(
            "{i}: at x = {:.2} m, y = {:.2} m; size {:.2} m² ({} cells); path distance {:.1} m\n",
            c.centroid[0], c.centroid[1], c.area_m2, c.size_cells, c.path_distance_m
        );
    }
    u += "Please provide the exploration plan first and then an exploration target in the specified JSON format.";
    Prompt { system: s, user: u }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidates(n: usize) -> Vec<Candidate> {
        (0..n)
            .map(|i| Candidate {
                centroid: [i as f64, 2.0],
                label_at: [i as f64, 2.1],
                size_cells: 10 * (i as u32 + 1),
                area_m2: 0.0251 * (i as f64 + 1.0),
                path_distance_m: 1.5 * i as f64,
            })
            .collect()
    }

    #[test]
    fn the_paper_prompt_is_filled_in() {
        let c = candidates(4);
        let mut facts = PromptFacts {
            total_steps: 2000,
            step: 137,
            candidates: &c,
            has_last_choice: false,
            robot: [0.0, 0.0, 0.0],
            last_choice: None,
        };
        let p = build(PromptStyle::Image, &facts);
        assert!(
            p.system
                .contains("a total of 2000 steps and this is step 137.")
        );
        assert!(p.system.contains("there are 4 candidate points"));
        assert!(p.system.contains("numbered from 0 to 3 in red color"));
        assert!(p.system.contains("please give -1 in the `target` entry"));
        assert!(!p.system.contains("yellow diamond"), "no choice yet");
        assert!(p.user.starts_with("I have a bird-eye view image"));
        facts.has_last_choice = true;
        let p = build(PromptStyle::Image, &facts);
        assert!(p.system.contains("marked with a yellow diamond shape"));
        assert!(p.system.ends_with("generate the full JSON."));
    }

    #[test]
    fn json_first_and_compact_ask_for_the_json_first() {
        let c = candidates(3);
        let facts = PromptFacts {
            total_steps: 400,
            step: 12,
            candidates: &c,
            has_last_choice: false,
            robot: [0.5, 0.25, 0.0],
            last_choice: None,
        };
        let p = build(PromptStyle::JsonFirst, &facts);
        assert!(p.system.contains("there are 3 candidate points"));
        assert!(
            p.system
                .contains("Start your reply with the exploration target")
        );
        assert!(
            !p.system
                .contains("Please provide a detailed exploration plan")
        );
        assert!(
            p.user
                .contains("JSON format first and then the exploration plan")
        );
        let p = build(PromptStyle::TextCompact, &facts);
        assert!(p.system.contains("from 0 to 2") && p.system.contains("JSON object first"));
        assert!(
            p.system.len() + p.user.len() < 900,
            "compact: {}",
            p.system.len()
        );
        assert!(
            p.user
                .starts_with("Step 12 of 400. Robot at x = 0.50 m, y = 0.25 m")
        );
        let line = p.user.lines().find(|l| l.starts_with("1: ")).unwrap();
        assert_eq!(line, "1: x = 1.00 m, y = 2.00 m; 0.05 m²; 1.5 m");
        assert!(follow_up_turn(3).contains("from 0 to 2, or -1"));
    }

    #[test]
    fn the_text_variant_lists_the_candidates() {
        let c = candidates(3);
        let facts = PromptFacts {
            total_steps: 500,
            step: 20,
            candidates: &c,
            has_last_choice: true,
            robot: [1.0, -2.5, std::f64::consts::FRAC_PI_2],
            last_choice: Some([3.0, 4.0]),
        };
        let p = build(PromptStyle::Text, &facts);
        assert!(!p.system.contains("blue star") && !p.user.contains("image"));
        assert!(p.system.contains("numbered from 0 to 2"));
        assert!(
            p.user
                .contains("x = 1.00 m, y = -2.50 m, heading 90 degrees")
        );
        assert!(p.user.contains("was at x = 3.00 m, y = 4.00 m"));
        let line = p.user.lines().find(|l| l.starts_with("2: ")).unwrap();
        assert_eq!(
            line,
            "2: at x = 2.00 m, y = 2.00 m; size 0.08 m² (30 cells); path distance 3.0 m"
        );
    }
}
