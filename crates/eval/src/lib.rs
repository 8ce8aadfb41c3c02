//! Evaluation metrics (PSNR, SSIM, LPIPS, depth MAE, ATE, completeness, coverage) and reports.
