"""Edge diffraction: UTD wedge coefficients (kernels), four-path ground model, curved legs, scene edges and
the diffraction stage (docs/physics.md, "Edge diffraction")."""
