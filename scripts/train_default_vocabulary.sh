#!/bin/sh
# Trains the default vocabulary shipped in zenslam/vocabulary/data/ (its corpus: data/README.md there).
# Run from the repository root with the benchmark clips in ../shared/data and zenslam installed;
# the same command gives the same file, byte for byte.
set -e
zenslam vocab train \
    kitti:../shared/data/kitti_odometry/sequences/06 \
    euroc:../shared/data/euroc/V1_01_easy_micro \
    synthetic:loop synthetic:figure_eight --synthetic-seeds 0-7 \
    --max-frames-per-source 100 \
    --branching 10 --depth 5 --seed 0 --max-iterations 30 \
    --output zenslam/vocabulary/data/orb_k10_L5.npz
