"""Training recipes, one per registered model: how its config becomes a DataModule, a
LightningModule and a model file (orchestration/recipe.py says what a recipe provides)."""
