# Campaigns (calibration/campaign.py; stage layer pipeline/campaign.py): a `measured` entry of
# several columns of one material (CAMPAIGN_NAMES, common.smk) calibrated as one parameter set of its
# model (model.json of the calibrated stage's rule calibrated_model: the diagnosis' answer under
# auto) by each route, every column validated at the answer and predicted from the others (leave one
# column out). Outputs under results/campaign/<name>/. Routes: CAMPAIGN_ROUTES, campaign_routes
# and campaign_gns_inputs (common.smk).


# One route: the face-centred CCD (every design point on every column), the Bayesian optimisation
# (one run per column per point), or the Bayesian optimisation on the GNS of the campaign's dataset
# (one rollout per column per point), then its validations and held-out predictions in DEM.
rule campaign_route:
    input:
        unpack(campaign_gns_inputs),
        measured=lambda w: config["measured"][w.name],
        model="results/calibrated/{name}/model.json",
    output:
        result="results/campaign/{name}/{route}.json",
        figure=report(
            "results/campaign/{name}/{route}.png",
            caption="../report/campaign_route.rst",
            category="2. Campaigns",
            subcategory="{name}",
            labels={"result": "route {route}"},
        ),
    log:
        "results/logs/campaign/campaign_route/{name}/{route}.log",
    benchmark:
        "results/benchmarks/campaign/campaign_route/{name}/{route}.tsv"
    wildcard_constraints:
        route="|".join(CAMPAIGN_ROUTES),
    conda:
        "../envs/pipeline.yaml"
    threads: lambda w: INVERSE["threads"] if w.route == "gns" else 1
    resources:
        runtime=240,
        mem_mb=4000,
    params:
        settings=CALIBRATION,
        diagnosis=config["diagnosis"],
        runout=RUNOUT,
        dem=DEM_ENGINE,
        # the GNS route's dataset and training, timed by their own jobs
        gns_cost=lambda w: gns_benchmarks(f"campaign_{w.name}") if w.route == "gns" else None,
    script:
        "../scripts/campaign_route.py"


# The answer: the route of the lowest validated campaign objective, every column against its band.
rule campaign:
    input:
        measured=lambda w: config["measured"][w.name],
        routes=lambda w: expand("results/campaign/{name}/{route}.json", name=w.name, route=campaign_routes(w.name)),
    output:
        result="results/campaign/{name}/campaign.json",
        figure=report(
            "results/campaign/{name}/campaign.png",
            caption="../report/campaign.rst",
            category="2. Campaigns",
            subcategory="{name}",
            labels={"result": "every column, and each from the others"},
        ),
    log:
        "results/logs/campaign/campaign/{name}.log",
    benchmark:
        "results/benchmarks/campaign/campaign/{name}.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    script:
        "../scripts/campaign.py"


rule campaign_section:
    input:
        results=expand("results/campaign/{name}/campaign.json", name=CAMPAIGN_NAMES),
        figures=expand("results/campaign/{name}/campaign.png", name=CAMPAIGN_NAMES),
    output:
        "results/report/campaign.md",
    log:
        "results/logs/campaign/campaign_section.log",
    benchmark:
        "results/benchmarks/campaign/campaign_section.tsv"
    localrule: True
    conda:
        "../envs/pipeline.yaml"
    script:
        "../scripts/campaign_section.py"


if CAMPAIGN_NAMES:
    FINAL_TARGETS += expand("results/campaign/{name}/campaign.json", name=CAMPAIGN_NAMES)
    REPORT_SECTIONS.append(("Campaigns", "results/report/campaign.md"))
