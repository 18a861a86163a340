"""Linear algebra of the fits: least squares by truncated SVD, its covariance, forward orthogonal term selection,
teacher-forced regressor rows."""
