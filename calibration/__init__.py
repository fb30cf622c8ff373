"""Calibration against measured data: the measured-data reader (measured), THE objective shared by
every calibration route (objective), and the inverse design, comparison and diagnosis built on them."""
