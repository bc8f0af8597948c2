"""Writing one USD asset: the package stage, its layers, LODs, textures, fallbacks, Storm network,
thumbnail, AR usdz, validation and the inspect summary."""
