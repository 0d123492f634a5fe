"""ImageNet backbones shared by the comparison networks of Tables I and II.

* :mod:`baselines.backbones.resnet`: ResNet-18/34/50/101/152 (torchvision's parameter names,
  optional three-convolution "deep" stem, DeepLab-style output stride 8/16);
* :mod:`baselines.backbones.densenet`: DenseNet-121 (torchvision's parameter names).

The modules are written from the published architectures (He et al. 2016, Huang et al. 2017)
and torchvision's documented layout, so that torchvision ImageNet state dicts load into them with
``load_state_dict`` unchanged. Importing this package imports no torch; its modules do.
"""
