"""homofac.light."""
