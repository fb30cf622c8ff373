"""One route of a campaign (several columns, one parameter set): results/campaign/<name>/<route>.json."""

import logging

from pipeline.campaign import campaign_runner, run_campaign_route

logging.basicConfig(filename=snakemake.log[0], level=logging.INFO, format="%(asctime)s %(message)s")
runner = campaign_runner(
    snakemake.input.measured,
    snakemake.input.model,
    snakemake.params.diagnosis,
    runout=snakemake.params.runout,
    dem=snakemake.params.dem,
    name=snakemake.wildcards.name,
)
gns = (
    {
        "model_path": snakemake.input.gns,
        "metadata_path": snakemake.input.metadata,
        "dataset_paths": snakemake.input.dataset,
        "cost_files": snakemake.params.gns_cost,
        "threads": snakemake.threads,
    }
    if snakemake.wildcards.route == "gns"
    else None
)
result = run_campaign_route(
    runner,
    snakemake.wildcards.route,
    snakemake.output.result,
    snakemake.output.figure,
    snakemake.params.settings,
    gns=gns,
)
logging.info("%s: %s at %s, campaign MSE %.4g", result.name, result.route, result.optimum.parameters, result.mse)
