"""How good a relief is: PSNR/SSIM, the rendered views against the photo, mask quality."""
