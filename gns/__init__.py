"""The learned simulator (GNS): a graph network trained on DEM trajectories of column collapse.

Modules, one idea each: graph (radius graph), features (node/edge features in labelled blocks),
network (encode-process-decode, knows nothing of physics), simulator (normalisation, features,
acceleration output and its inverse, semi-implicit Euler), data (HDF5 windows for training),
train, rollout (differentiable, checkpointed), evaluate (runout against DEM).
"""
