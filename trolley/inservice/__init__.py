"""In-service vehicle lateral alignment estimation (Munoz 2021): models, truth simulator, Kalman estimator."""
