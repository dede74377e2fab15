"""Files: model files and training checkpoints written and read back, atomic writes, result folders.

* ``checkpoint`` — model files (``save_model`` / ``load_model``) and training checkpoints;
* ``model_files`` — a model file read and verified before use (zip, tensors, play options);
* ``files`` — atomic writes and the checks before a new file or folder; ``outputs`` — one writer per
  output folder, results moved in with their record ``run.json``; ``shipped`` — the shipped models by name.
"""
