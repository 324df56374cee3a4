#!/usr/bin/env bash
# The garden's textures, made with ImageMagick 6 (Debian 12's `imagemagick`): a lawn (opaque),
# a lattice fence and a hedge of leaves (RGBA: their alpha is the cut-out), all 256x256 PNG.
# Seeded, so the same ImageMagick makes the same images; garden.glb holds the images it was made
# from, so the tests never run this.
set -euo pipefail
cd "$(dirname "$0")"
# Lawn: green plasma noise, opaque.
convert -seed 7 -size 256x256 plasma:fractal -colorspace gray -blur 0x1 -auto-level -colorspace sRGB +level-colors '#1f4a17,#5aa83c' \
  -alpha off PNG24:lawn.png
# Fence: wooden diagonal lattice on a transparent background, two bar directions, soft grain.
convert -size 256x256 xc:none -stroke '#8b5a2b' -strokewidth 18 \
  -draw 'line -32,0 256,288' -draw 'line 96,0 256,160' -draw 'line 0,96 160,256' \
  -draw 'line 288,0 0,288' -draw 'line 160,0 0,160' -draw 'line 256,96 96,256' \
  -draw 'line 0,8 256,8' -draw 'line 0,248 256,248' \
  \( -seed 11 -size 256x256 plasma:fractal -colorspace gray -blur 0x2 -auto-level -colorspace sRGB +level-colors '#5a3418,#b07a40' \) \
  -compose SrcIn -composite PNG32:fence.png
# Hedge: leafy colour, alpha from a thresholded noise field (irregular holes and rims).
convert -seed 23 -size 256x256 plasma:fractal -colorspace gray -blur 0x1 -auto-level -colorspace sRGB +level-colors '#0f3f0f,#4fb04f' \
  \( -seed 29 -size 256x256 plasma:fractal -colorspace gray -blur 0x4 -equalize -threshold 45% \) \
  -alpha off -compose CopyOpacity -composite PNG32:hedge.png
