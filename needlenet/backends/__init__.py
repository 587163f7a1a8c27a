"""Estimation back ends of the five papers: RANSAC, Kalman filters, particle filters, EKF,
the bicycle model, insertion detection and speckle tracking."""
