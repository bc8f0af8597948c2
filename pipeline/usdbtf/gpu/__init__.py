"""Real-time BTF preview: the GPU layout of a compressed BTF (:mod:`.tables`), the shaders
built from one GLSL source (:mod:`.shaders`: Storm glslfx, MaterialX genglsl, headless
harness), the headless OpenGL renderer that checks them against the CPU renderer
(:mod:`.headless`) and the glslang compile check (:mod:`.glslang`)."""
