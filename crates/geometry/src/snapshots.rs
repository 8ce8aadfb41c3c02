//! Map snapshots kept for a consumer that runs L frames behind the mapper (the map lag, SPEC §1:
//! tracking, occupancy, the planner and the scorer of frame k all read the snapshot of frame
//! k − 1 − L, so a seeded run is deterministic whatever the timing).
//!
//! [`LaggedSnapshots`] is the one bookkeeping every such consumer needs: snapshots by the last
//! frame they include, the one frame k needs ([`required_snapshot`]), reuse of the newest
//! decoded map while the keyframe that made it is unchanged, and dropping what no later frame
//! can need. It is generic over what a snapshot is (a shared Gaussian map, a scoring map with
//! ids, a map with its keyframe version), so that it lives below every crate that keeps maps.

use std::collections::BTreeMap;

/// The map snapshot frame `k` is tracked, gridded, planned and scored against under map lag
/// `lag`: k − 1 − L, clamped at frame 0 (the first frames all use the first snapshot).
pub fn required_snapshot(k: u64, lag: u64) -> u64 {
    k.saturating_sub(1 + lag)
}

/// Snapshots by the last frame they include, from the one the next frame needs on (frames
/// are consumed in order, so older ones are dropped as soon as a frame is done).
#[derive(Debug, Clone)]
pub struct LaggedSnapshots<T> {
    lag: u64,
    by_frame: BTreeMap<u64, T>,
}

impl<T> LaggedSnapshots<T> {
    /// An empty cache for a consumer with map lag `lag` frames.
    pub fn new(lag: u64) -> Self {
        Self {
            lag,
            by_frame: BTreeMap::new(),
        }
    }

    /// The map lag L in frames.
    pub fn lag(&self) -> u64 {
        self.lag
    }

    /// The frame whose snapshot frame `k` needs ([`required_snapshot`]).
    pub fn needed(&self, k: u64) -> u64 {
        required_snapshot(k, self.lag)
    }

    /// Stores the snapshot that includes every frame ≤ `frame_id`.
    pub fn insert(&mut self, frame_id: u64, snapshot: T) {
        self.by_frame.insert(frame_id, snapshot);
    }

    /// The newest snapshot stored (the one a new snapshot of the same keyframe may share).
    pub fn newest(&self) -> Option<&T> {
        self.by_frame.values().next_back()
    }

    /// The snapshot frame `k` needs, once it has arrived (never a newer or older one that
    /// happens to be there).
    pub fn for_frame(&self, k: u64) -> Option<&T> {
        self.by_frame.get(&self.needed(k))
    }

    /// Keeps the snapshot frame `k` needs and the newer ones; drops the older ones, which no
    /// frame after `k` can need.
    pub fn retain_needed_from(&mut self, k: u64) {
        self.by_frame = self.by_frame.split_off(&self.needed(k));
    }

    /// How many snapshots are stored.
    pub fn len(&self) -> usize {
        self.by_frame.len()
    }

    /// True when no snapshot is stored.
    pub fn is_empty(&self) -> bool {
        self.by_frame.is_empty()
    }
}

impl<T: Clone> LaggedSnapshots<T> {
    /// Stores the snapshot of frame `frame_id`, sharing the newest stored one when `same` says
    /// it holds the same map (snapshots of one keyframe do: a map changes only at keyframes),
    /// else the one `decode` makes; a decoding error is returned and nothing is stored.
    pub fn insert_reusing<E>(
        &mut self,
        frame_id: u64,
        same: impl FnOnce(&T) -> bool,
        decode: impl FnOnce() -> Result<T, E>,
    ) -> Result<(), E> {
        let snapshot = match self.newest().filter(|s| same(s)) {
            Some(s) => s.clone(),
            None => decode()?,
        };
        self.insert(frame_id, snapshot);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn required_snapshot_is_k_minus_one_minus_lag_clamped_at_zero() {
        assert_eq!(required_snapshot(0, 0), 0);
        assert_eq!(required_snapshot(1, 0), 0);
        assert_eq!(required_snapshot(5, 0), 4);
        assert_eq!(required_snapshot(5, 3), 1);
        assert_eq!(required_snapshot(4, 3), 0);
        assert_eq!(required_snapshot(2, 10), 0);
    }

    /// Frame k gets exactly snapshot k − 1 − L, not a newer one already there nor an older
    /// one; once frame k is done, older snapshots go and the needed one stays.
    #[test]
    fn frames_get_exactly_their_lagged_snapshot() {
        let mut maps = LaggedSnapshots::new(2);
        assert_eq!(maps.lag(), 2);
        for k in [0, 1, 3] {
            maps.insert(k, k * 10);
        }
        assert_eq!(maps.for_frame(0), Some(&0), "clamped at the first snapshot");
        assert_eq!(maps.for_frame(4), Some(&10));
        assert_eq!(maps.for_frame(5), None, "snapshot 2 has not arrived");
        assert_eq!(maps.for_frame(6), Some(&30));
        assert_eq!(maps.newest(), Some(&30));
        maps.retain_needed_from(4);
        assert_eq!(maps.len(), 2);
        assert_eq!(maps.for_frame(4), Some(&10), "the needed one stays");
        maps.retain_needed_from(6);
        assert_eq!(maps.for_frame(4), None);
        assert!(!maps.is_empty());
        maps.retain_needed_from(100);
        assert!(maps.is_empty());
    }

    /// A snapshot of the same keyframe shares the newest decoded map (decoding is skipped); a
    /// new keyframe is decoded; a decoding error stores nothing.
    #[test]
    fn snapshots_of_one_keyframe_share_the_decoded_map() {
        let mut maps: LaggedSnapshots<(u64, Arc<Vec<u8>>)> = LaggedSnapshots::new(0);
        let decode = |keyframe: u64| move || Ok::<_, String>((keyframe, Arc::new(vec![1, 2])));
        maps.insert_reusing(1, |_| unreachable!("empty"), decode(1))
            .unwrap();
        maps.insert_reusing(2, |m| m.0 == 1, || Err("decoded again".to_string()))
            .unwrap();
        let (a, b) = (maps.for_frame(2).unwrap(), maps.for_frame(3).unwrap());
        assert!(Arc::ptr_eq(&a.1, &b.1));
        maps.insert_reusing(3, |m| m.0 == 3, decode(3)).unwrap();
        assert_eq!(maps.for_frame(4).unwrap().0, 3);
        let e = maps.insert_reusing(4, |m| m.0 == 4, || Err("bad map".to_string()));
        assert_eq!(e, Err("bad map".to_string()));
        assert_eq!(maps.for_frame(5), None);
    }
}
