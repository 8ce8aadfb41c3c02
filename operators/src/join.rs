//! The per-frame join shared by the lockstep pipeline operators (occupancy, frontier, planner,
//! scorer, follower): inputs that belong to the same frame (the grid, the pose estimate, the
//! frontier regions, the map snapshot of frame k) arrive on different ports in any order; the
//! join keeps one slot per frame id until the operator has everything it needs for that frame.
//!
//! The slot type is the operator's own struct of `Option` fields, so each operator states what
//! "complete" means for it; the join only keeps the slots ordered by frame id and drops the
//! ones that can no longer be used, so a run's results never depend on message timing.

use std::collections::BTreeMap;

/// Slots of per-frame inputs, ordered by frame id.
#[derive(Debug)]
pub struct FrameJoin<S> {
    slots: BTreeMap<u64, S>,
}

impl<S> Default for FrameJoin<S> {
    fn default() -> Self {
        Self {
            slots: BTreeMap::new(),
        }
    }
}

impl<S: Default> FrameJoin<S> {
    /// An empty join.
    pub fn new() -> Self {
        Self::default()
    }

    /// The slot of `frame`, created empty when it is the first input of that frame.
    pub fn slot(&mut self, frame: u64) -> &mut S {
        self.slots.entry(frame).or_default()
    }

    /// The slot of `frame`, if any input of it arrived.
    pub fn get(&self, frame: u64) -> Option<&S> {
        self.slots.get(&frame)
    }

    /// Removes and returns the slot of `frame`.
    pub fn take(&mut self, frame: u64) -> Option<S> {
        self.slots.remove(&frame)
    }

    /// Removes and returns the OLDEST slot when `ready` accepts it; `None` when there is no slot
    /// or the oldest one is incomplete (frames are processed strictly in order).
    pub fn pop_ready(&mut self, ready: impl Fn(&S) -> bool) -> Option<(u64, S)> {
        let (_, first) = self.slots.first_key_value()?;
        if !ready(first) {
            return None;
        }
        self.slots.pop_first()
    }

    /// Like [`Self::pop_ready`], with the frame id passed to `ready` as well (for inputs kept
    /// outside the slot, e.g. a lagged map snapshot).
    pub fn pop_ready_by(&mut self, ready: impl Fn(u64, &S) -> bool) -> Option<(u64, S)> {
        let (&k, first) = self.slots.first_key_value()?;
        if !ready(k, first) {
            return None;
        }
        self.slots.pop_first()
    }

    /// Drops every slot of a frame older than `frame` (inputs that are no longer needed).
    pub fn discard_before(&mut self, frame: u64) {
        self.slots = self.slots.split_off(&frame);
    }

    /// Frames with a pending slot.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether no slot is pending.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default, Debug, PartialEq)]
    struct Slot {
        grid: Option<u32>,
        pose: Option<u32>,
    }

    fn complete(s: &Slot) -> bool {
        s.grid.is_some() && s.pose.is_some()
    }

    /// Inputs of frames 0..3 arriving interleaved and out of order come out as whole frames in
    /// frame order, and never before the frame is complete.
    #[test]
    fn frames_come_out_whole_and_in_order() {
        let mut join = FrameJoin::<Slot>::new();
        join.slot(1).grid = Some(10);
        join.slot(0).pose = Some(0);
        assert_eq!(join.pop_ready(complete), None, "frame 0 lacks its grid");
        join.slot(1).pose = Some(11);
        // Frame 1 is complete but frame 0 is older and still incomplete: nothing comes out.
        assert_eq!(join.pop_ready(complete), None);
        join.slot(0).grid = Some(0);
        join.slot(2).grid = Some(20);
        let mut out = Vec::new();
        while let Some((k, s)) = join.pop_ready(complete) {
            out.push((k, s.grid.unwrap() + s.pose.unwrap()));
        }
        assert_eq!(out, vec![(0, 0), (1, 21)]);
        assert_eq!(join.len(), 1, "frame 2 waits for its pose");
    }

    /// A request-driven operator reads the slot of the requested frame and then drops the older
    /// frames; the requested and newer frames stay.
    #[test]
    fn discard_before_keeps_the_requested_and_newer_frames() {
        let mut join = FrameJoin::<Slot>::new();
        for k in 0..5 {
            join.slot(k).grid = Some(k as u32);
        }
        assert_eq!(join.get(3).and_then(|s| s.grid), Some(3));
        join.discard_before(3);
        assert_eq!(join.len(), 2);
        assert!(join.get(2).is_none() && join.get(3).is_some() && join.get(4).is_some());
        assert_eq!(join.take(4).and_then(|s| s.grid), Some(4));
        assert_eq!(join.len(), 1);
        assert!(!join.is_empty());
    }
}
