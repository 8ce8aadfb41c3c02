//! The `mc_free_space` model Fisher is an unbiased estimator of `N·E_{x∼U(free)}[H(x)]`: with a
//! known view-information function, the mean over seeded replicas of the estimate matches the
//! exact expectation over the clear cells (also for a Gaussian that appeared halfway, whose
//! estimate is rescaled from the views taken after it appeared).

use activemap_active::candidates::sample_free_space_poses;
use activemap_active::information::PARAMS;
use activemap_active::model::{ModelFisher, ModelSample};
use activemap_active::{FisherConfig, ModelFisherSource};
use activemap_geometry::PlanarPose;
use activemap_planning::OccupancyGrid;
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A known "view information": H of Gaussian 0 and 1 as functions of the pose.
fn h(pose: &PlanarPose) -> [f32; PARAMS] {
    let mut d = [0.0f32; PARAMS];
    d[0] = (pose.x * pose.x) as f32;
    d[1] = (1.0 + pose.yaw.cos()) as f32;
    d[2] = (pose.y + 2.0) as f32;
    d
}

#[test]
fn monte_carlo_model_fisher_is_unbiased() {
    // An L-shaped room: the clear cells are a known, non-symmetric set.
    let rows: Vec<String> = (0..30)
        .map(|r| {
            (0..40)
                .map(|c| {
                    let inside = (2..28).contains(&r) && (2..38).contains(&c);
                    let cut = r < 15 && c > 20;
                    if inside && !cut { '.' } else { '#' }
                })
                .collect()
        })
        .collect();
    let rows: Vec<&str> = rows.iter().map(|s| s.as_str()).collect();
    let grid = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
    let clear = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
    let g = grid.geometry;
    let cells: Vec<_> = (0..g.len())
        .map(|i| g.cell_at(i))
        .filter(|c| clear.is_clear(*c))
        .collect();
    assert!(cells.len() > 300);
    // Exact expectations: uniform in each cell's square (side s), cells equally likely.
    let s = g.resolution;
    let n = cells.len() as f64;
    let ex2 = cells
        .iter()
        .map(|c| g.center(*c).x.powi(2) + s * s / 12.0)
        .sum::<f64>()
        / n;
    let ey = cells.iter().map(|c| g.center(*c).y).sum::<f64>() / n;
    let expected = [ex2, 1.0, ey + 2.0];

    let poses = 16;
    let config = FisherConfig {
        model_fisher: ModelFisherSource::McFreeSpace,
        mc_poses: poses,
        ..FisherConfig::default()
    };
    let replicas = 400;
    let mut late = Vec::new();
    let mut full = Vec::new();
    for r in 0..replicas {
        let mut rng = ChaCha8Rng::seed_from_u64(1000 + r);
        let mut model = ModelFisher::new(&config);
        for (k, p) in sample_free_space_poses(&clear, poses, &mut rng)
            .iter()
            .enumerate()
        {
            // Gaussian 1 is added after the eighth view.
            let mut diagonal = vec![(0u64, h(p))];
            let max = if k >= 8 {
                diagonal.push((1, h(p)));
                1
            } else {
                0
            };
            model.push(ModelSample {
                diagonal,
                max_real_id: Some(max),
                generation: 0,
            });
        }
        full.push(model.information(0));
        late.push(model.information(1));
    }
    for (estimates, views) in [(&full, poses), (&late, 8)] {
        for (k, e) in expected.iter().enumerate() {
            let values: Vec<f64> = estimates.iter().map(|d| d[k]).collect();
            let mean = values.iter().sum::<f64>() / replicas as f64;
            let var =
                values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (replicas - 1) as f64;
            let standard_error = (var / replicas as f64).sqrt();
            let truth = poses as f64 * e;
            assert!(
                (mean - truth).abs() < 4.0 * standard_error + 1e-6 * truth.abs(),
                "entry {k} from {views} views: mean {mean} vs N·E[H] = {truth} (s.e. {standard_error})"
            );
        }
    }
}
