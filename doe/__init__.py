"""Design of experiments: full-factorial designs (design), response-surface regression and ANOVA
(regression), figures (plots) and the DoE calibration study of a measured column (study)."""
