"""The stage layer: what each Snakemake job does, between the packages (dem, gns, doe, calibration:
physics and methods) and workflow/ (rules and thin scripts). One module per stage, each with its
entry functions and its report section; config validation; the report; the benchmark reader.
workflow/scripts/* import only this package; the packages never import it and know nothing of
Snakemake.
"""
