//! Human arm-hand model, anthropometry, demonstration formats, synthetic study generator.
