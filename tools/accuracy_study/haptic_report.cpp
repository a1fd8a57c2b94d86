// Part 2 of the accuracy study, the measures: per method of each case, over the ticks every
// method has (those served by a snapshot, after HapticCase::settle_s):
//  * force error against R1 and against R2: relative RMS sqrt(sum |F - F_ref|^2 / sum |F_ref|^2)
//    and max |F - F_ref| [N];
//  * stiffness felt within a snapshot period: per period (the ticks one snapshot serves), the
//    least-squares slope k = -sum dF . dx / sum |dx|^2 of the force change against the device's
//    displacement since the period's first tick (periods where the device moves >= 1 um), median
//    over the periods [N/m]; R1's on the same periods beside it;
//  * penetration: the largest linearised penetration of the rendered tool [mm];
//  * energy into the hand: sum_j F_j . (x_j+1 - x_j) over the closed motion [mJ] (<= 0: the
//    rendering took energy from the hand, passive; > 0: it gave energy, active);
//  * time per tick: median [us] (R1, R2: the full step).

#include <algorithm>
#include <cmath>
#include <sstream>

#include "study.h"

namespace tactus::study {
namespace {

struct Measures {
  long compared = 0;
  double ref_peak_n = 0.0;
  double err_r1_rel = 0.0, err_r1_max_n = 0.0;
  double err_r2_rel = 0.0, err_r2_max_n = 0.0;
  double stiffness_npm = 0.0, stiffness_r1_npm = 0.0;
  int stiffness_periods = 0;
  double penetration_m = 0.0;
  double energy_j = 0.0;
  double tick_s = 0.0;
};

bool compared(const HapticCase& c, std::size_t j) {
  if (static_cast<double>(j) < c.settle_s * c.rate_hz - 1e-9) return false;
  for (const MethodSeries& s : c.series) {
    if (!s.valid[j]) return false;
  }
  return true;
}

// Per-period slopes of `s` (and of R1 on the same periods).
void stiffness(const HapticCase& c, const MethodSeries& s, Measures& m) {
  const MethodSeries& r1 = c.series.at(0);
  std::vector<double> k_s, k_r1;
  const std::size_t n = s.force.size();
  std::size_t j0 = 0;
  while (j0 < n) {
    std::size_t j1 = j0;
    while (j1 < n && c.snapshot[j1] == c.snapshot[j0]) ++j1;
    if (c.snapshot[j0] >= 0 && compared(c, j0)) {
      double num = 0.0, num_r1 = 0.0, den = 0.0, reach = 0.0;
      for (std::size_t j = j0 + 1; j < j1; ++j) {
        const Eigen::Vector3d dx = c.device_pos[j] - c.device_pos[j0];
        num += (s.force[j] - s.force[j0]).dot(dx);
        num_r1 += (r1.force[j] - r1.force[j0]).dot(dx);
        den += dx.squaredNorm();
        reach = std::max(reach, dx.norm());
      }
      if (reach >= 1e-6) {
        k_s.push_back(-num / den);
        k_r1.push_back(-num_r1 / den);
      }
    }
    j0 = j1;
  }
  m.stiffness_npm = median(k_s);
  m.stiffness_r1_npm = median(k_r1);
  m.stiffness_periods = static_cast<int>(k_s.size());
}

Measures measure(const HapticCase& c, const MethodSeries& s) {
  Measures m;
  const MethodSeries& r1 = c.series.at(0);
  const MethodSeries& r2 = c.series.at(1);
  double n1 = 0.0, d1 = 0.0, n2 = 0.0, d2 = 0.0;
  std::vector<double> times;
  const std::size_t n = s.force.size();
  for (std::size_t j = 0; j < n; ++j) {
    if (!compared(c, j)) continue;
    ++m.compared;
    const double e1 = (s.force[j] - r1.force[j]).norm();
    const double e2 = (s.force[j] - r2.force[j]).norm();
    n1 += e1 * e1;
    d1 += r1.force[j].squaredNorm();
    n2 += e2 * e2;
    d2 += r2.force[j].squaredNorm();
    m.err_r1_max_n = std::max(m.err_r1_max_n, e1);
    m.err_r2_max_n = std::max(m.err_r2_max_n, e2);
    m.ref_peak_n = std::max(m.ref_peak_n, r1.force[j].norm());
    m.penetration_m = std::max(m.penetration_m, s.penetration[j]);
    times.push_back(s.time_s[j]);
    if (j + 1 < n) m.energy_j += s.force[j].dot(c.device_pos[j + 1] - c.device_pos[j]);
  }
  m.err_r1_rel = d1 > 0.0 ? std::sqrt(n1 / d1) : 0.0;
  m.err_r2_rel = d2 > 0.0 ? std::sqrt(n2 / d2) : 0.0;
  m.tick_s = median(times);
  stiffness(c, s, m);
  return m;
}

}  // namespace

std::string hapticCsv(const std::vector<HapticCase>& cases, const std::string& mesh) {
  std::ostringstream out;
  out << "motion,mesh,rate_hz,sim_hz,snapshot_w,method,label,sweeps_per_tick,ticks_compared,"
         "force_r1_peak_n,err_r1_rel_rms,err_r1_max_n,err_r2_rel_rms,err_r2_max_n,"
         "stiffness_npm,stiffness_r1_npm,stiffness_periods,max_penetration_mm,"
         "energy_to_hand_mj,tick_us_median\n";
  for (const HapticCase& c : cases) {
    for (const MethodSeries& s : c.series) {
      const Measures m = measure(c, s);
      out << c.motion << ',' << mesh << ',' << fmtG(c.rate_hz) << ',' << fmtG(1.0 / c.sim_h_s)
          << ',' << c.snapshot_w << ',' << s.method << ',' << s.label << ',' << s.sweeps << ','
          << m.compared << ','
          << fmtG(m.ref_peak_n) << ',' << fmtG(m.err_r1_rel) << ',' << fmtG(m.err_r1_max_n)
          << ',' << fmtG(m.err_r2_rel) << ',' << fmtG(m.err_r2_max_n) << ','
          << fmtG(m.stiffness_npm) << ',' << fmtG(m.stiffness_r1_npm) << ','
          << m.stiffness_periods << ',' << fmtG(1e3 * m.penetration_m) << ','
          << fmtG(1e3 * m.energy_j) << ',' << fmtG(1e6 * m.tick_s) << '\n';
    }
  }
  return out.str();
}

std::string hapticSeries(const HapticCase& c, double t0_s) {
  std::string out;
  std::vector<double> t(c.device_pos.size());
  for (std::size_t j = 0; j < t.size(); ++j) t[j] = t0_s + static_cast<double>(j) / c.rate_hz;
  for (const MethodSeries& s : c.series) {
    const std::string name = s.method == "r1" ? "R1" : s.method == "r2" ? "R2" : s.label;
    appendSeries(out, name, t, s.force, &s.valid);
  }
  return out;
}

}  // namespace tactus::study
