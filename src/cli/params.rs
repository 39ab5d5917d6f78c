//! The paper's settings as command-line arguments, shared by every command that takes them;
//! their defaults come from the library's ([`DetectParams::default`], [`RelaxParams::default`]).

use photonkit::detect::DetectParams;
use photonkit::relax::RelaxParams;

/// Feature detection's settings (Eq. 1–7).
#[derive(clap::Args, Clone, Debug)]
pub struct DetectArgs {
    /// Kc: neighbours in the PCA kernel (and the gradient kernel); at least 3.
    #[arg(long, default_value_t = DetectParams::default().kc)]
    pub kc: usize,
    /// β of Eq. 1: the parameter-space radius in units of the mean photon spacing sqrt(Kc/(πρ)).
    #[arg(value_parser = super::finite_f32, long, default_value_t = DetectParams::default().beta)]
    pub beta: f32,
    /// Times a constrained photon's parameter ball may be doubled when its neighbours reach the
    /// ball's outer fifth (a stretched map from parameters to the surface, not an edge); 0 keeps
    /// the paper's fixed ball (docs/parameter-ball.md).
    #[arg(long, value_name = "N", default_value_t = DetectParams::default().growths)]
    pub growths: u32,
    /// For maps whose photons carry their wavelength (a dispersive scene): the visible range's
    /// length in parameter space, in units of the spread of the emitter's other parameters
    /// (docs/spectral.md). Larger separates colours more.
    #[arg(value_parser = super::finite_f32, long, value_name = "S",
          default_value_t = DetectParams::default().spectral_scale)]
    pub spectral_scale: f32,
    /// k of the parameter-space density estimate ρ = k/(π r_k²) of Eq. 1; default Kc.
    #[arg(long, value_name = "K")]
    pub k_density: Option<usize>,
}

impl DetectArgs {
    /// `p` with these settings.
    pub fn apply(&self, p: DetectParams) -> DetectParams {
        DetectParams {
            kc: self.kc,
            beta: self.beta,
            growths: self.growths,
            spectral_scale: self.spectral_scale,
            k_density: self.k_density,
            ..p
        }
    }

    /// These settings as command-line arguments (for a stage run as its subcommand).
    pub fn to_argv(&self) -> Vec<String> {
        let mut v = vec![
            "--kc".to_string(),
            self.kc.to_string(),
            "--beta".into(),
            self.beta.to_string(),
            "--growths".into(),
            self.growths.to_string(),
            "--spectral-scale".into(),
            self.spectral_scale.to_string(),
        ];
        if let Some(k) = self.k_density {
            v.extend(["--k-density".to_string(), k.to_string()]);
        }
        v
    }
}

/// Relaxation's settings (Eq. 8–9).
#[derive(clap::Args, Clone, Debug)]
pub struct RelaxArgs {
    /// R: relaxation iterations (the paper: 7 before the collapse and 7 after; `pipeline` and
    /// `compare` run R in each phase).
    #[arg(short = 'R', long, default_value_t = RelaxParams::default().iterations)]
    pub iterations: usize,
    /// Kf: neighbours in the repulsion force of Eq. 8.
    #[arg(long, default_value_t = RelaxParams::default().kf)]
    pub kf: usize,
    /// For maps whose photons carry their wavelength (a dispersive scene), relaxing after the
    /// collapse: a photon's Kf neighbours are only those within NM nanometres of its own
    /// wavelength, so each colour spreads evenly among itself and every kernel holds an even
    /// sample of the spectrum (docs/spectral.md); 0 takes every wavelength.
    #[arg(value_parser = super::finite_f32, long, value_name = "NM",
          default_value_t = RelaxParams::default().spectral_window)]
    pub spectral_window: f32,
}

impl RelaxArgs {
    /// `p` with these settings.
    pub fn apply(&self, p: RelaxParams) -> RelaxParams {
        RelaxParams { iterations: self.iterations, kf: self.kf, spectral_window: self.spectral_window, ..p }
    }

    /// These settings as command-line arguments (for a stage run as its subcommand).
    pub fn to_argv(&self) -> Vec<String> {
        vec![
            "--iterations".into(),
            self.iterations.to_string(),
            "--kf".into(),
            self.kf.to_string(),
            "--spectral-window".into(),
            self.spectral_window.to_string(),
        ]
    }
}
