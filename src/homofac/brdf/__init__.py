"""homofac.brdf."""
