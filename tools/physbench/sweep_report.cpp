// physbench --sweep's reports (sweep.h): the runs as time-against-error points with their
// Pareto fronts, the CSV, one gnuplot plot per scene and the Markdown with its reading.
#include <sys/wait.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <tuple>
#include <utility>

#include "sweep.h"

namespace phys::bench {

namespace {

std::string fmt9(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.9g", v);
  return b;
}

bool ran(const SweepPoint& p) {
  return p.status != RunStatus::Error && p.status != RunStatus::CannotRun;
}

/// A point that can be compared and plotted: an error value and a measured time.
bool valued(const SweepPoint& p) {
  return p.error && std::isfinite(p.msMedian) && p.msMedian > 0;
}

/// a is no slower and no less accurate than b, and strictly better in one (both valued).
bool dominates(const SweepPoint& a, const SweepPoint& b) {
  return a.msMedian <= b.msMedian && *a.error <= *b.error &&
         (a.msMedian < b.msMedian || *a.error < *b.error);
}

bool isPhys(const SweepPoint& p) {
  return p.engine == "phys";
}

/// "6x2" for a phys run, "10 it" for a peer's, "default" when the run kept its own budget.
std::string budgetText(const SweepPoint& p) {
  if (isPhys(p) && p.substeps > 0 && p.iterations > 0)
    return std::to_string(p.substeps) + "x" + std::to_string(p.iterations);
  if (!isPhys(p) && p.iterations > 0) return std::to_string(p.iterations) + " it";
  return "default";
}

/// A phys run at its preset's own budget: the suite's column without a budget in its label.
bool ownBudget(const SweepPoint& p) {
  return isPhys(p) && p.label == p.config;
}

/// The run in sentences: its label, with the budget for a preset's own column.
std::string runName(const SweepPoint& p) {
  const std::string budget = budgetText(p);
  return ownBudget(p) && budget != "default" ? p.label + " " + budget : p.label;
}

/// The scenes of the points: the report's order first, then any others as they come.
std::vector<std::string> sceneOrder(const std::vector<std::string>& reportScenes,
                                    const std::vector<SweepPoint>& points) {
  std::vector<std::string> out;
  auto add = [&](const std::string& s) {
    if (std::find(out.begin(), out.end(), s) == out.end()) out.push_back(s);
  };
  for (const std::string& s : reportScenes) {
    for (const SweepPoint& p : points) {
      if (p.scene != s) continue;
      add(s);
      break;
    }
  }
  for (const SweepPoint& p : points) add(p.scene);
  return out;
}

/// One series: a config of one engine, with its points sorted by time (runs without a time
/// last, then by budget).
struct Series {
  std::string engine, config;
  std::vector<const SweepPoint*> points;
};

std::vector<Series> seriesOf(const std::vector<SweepPoint>& points, const std::string& scene) {
  std::vector<Series> out;
  for (const SweepPoint& p : points) {
    if (p.scene != scene) continue;
    auto s = std::find_if(out.begin(), out.end(), [&](const Series& x) {
      return x.engine == p.engine && x.config == p.config;
    });
    if (s == out.end()) s = out.insert(out.end(), Series{p.engine, p.config, {}});
    s->points.push_back(&p);
  }
  for (Series& s : out) {
    std::stable_sort(
        s.points.begin(), s.points.end(), [](const SweepPoint* a, const SweepPoint* b) {
          const double inf = std::numeric_limits<double>::infinity();
          auto key = [&](const SweepPoint* p) {
            return std::make_tuple(ran(*p) ? p->msMedian : inf, p->substeps, p->iterations);
          };
          return key(a) < key(b);
        });
  }
  return out;
}

/// "top_drift (m)": the metric's name with its unit when the scene's main metric is it.
std::string metricText(const std::string& scene, const std::string& metric) {
  const MainMetric mm = mainMetricFor(scene);
  return mm.name == metric && !mm.unit.empty() ? metric + " (" + mm.unit + ")" : metric;
}

/// Where errors <= 0 go on a log axis: a tenth of the scene's smallest positive error, or
/// 1e-6 when none is positive. Empty when every error is positive.
std::optional<double> logFloor(const std::vector<const SweepPoint*>& valuedPoints) {
  double minPositive = 0;
  bool clamp = false;
  for (const SweepPoint* p : valuedPoints) {
    if (*p->error <= 0) clamp = true;
    if (*p->error > 0 && (minPositive == 0 || *p->error < minPositive)) minPositive = *p->error;
  }
  if (!clamp) return std::nullopt;
  return minPositive > 0 ? minPositive / 10 : 1e-6;
}

/// The scene's name as a file name: characters other than [A-Za-z0-9_.-] become '_'.
std::string fileStem(const std::string& scene) {
  std::string s = scene;
  for (char& c : s) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-' && c != '.') c = '_';
  }
  return s.empty() ? "_" : s;
}

/// A double-quoted gnuplot string (line breaks as \\n).
std::string gpString(const std::string& s) {
  std::string q = "\"";
  for (char c : s) {
    if (c == '\n') {
      q += "\\n";
      continue;
    }
    if (c == '"' || c == '\\') q += '\\';
    q += c;
  }
  return q + "\"";
}

/// A single-quoted shell word.
std::string shellWord(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

/// Runs a shell command; returns its output and sets *status to its exit status (-1 when it
/// could not be started or did not exit).
std::string runCommand(const std::string& command, int* status) {
  *status = -1;
  FILE* f = popen(command.c_str(), "r");
  if (!f) return {};
  std::string out;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) out.append(buf, n);
  int st = pclose(f);
  if (st != -1 && WIFEXITED(st)) *status = WEXITSTATUS(st);
  return out;
}

// Series styles: phys presets filled points and solid fronts, peers open points and dashed
// fronts, each in its own colour.
const char* kPhysColours[] = {"#1f77b4", "#2ca02c", "#9467bd", "#17becf",
                              "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"};
const char* kPeerColours[] = {"#d62728", "#ff7f0e", "#000000", "#8b0000"};
const int kPhysPointTypes[] = {7, 5, 9, 11, 13, 15};
const int kPeerPointTypes[] = {6, 4, 8, 10, 12, 14};

/// The .dat and .gp of one scene (nothing when no point has a value).
struct PlotFiles {
  std::string dat, gp;
};

PlotFiles plotFiles(const std::vector<SweepPoint>& points, const std::string& scene) {
  const std::string stem = fileStem(scene);
  std::vector<Series> series = seriesOf(points, scene);
  std::vector<const SweepPoint*> all;
  for (const Series& s : series) {
    for (const SweepPoint* p : s.points) {
      if (valued(*p)) all.push_back(p);
    }
  }
  if (all.empty()) return {};
  const std::optional<double> floor = logFloor(all);
  auto plotted = [&](const SweepPoint& p) { return floor && *p.error <= 0 ? *floor : *p.error; };

  std::ostringstream dat, plot;
  dat << "# physbench --sweep, scene " << scene << ": per config two index blocks, its runs "
      << "with a value by ms, then its front.\n# ms_median error_plotted error budget\n";
  int block = 0, phys = 0, peers = 0;
  for (const Series& s : series) {
    std::vector<const SweepPoint*> pts;
    for (const SweepPoint* p : s.points) {
      if (valued(*p)) pts.push_back(p);
    }
    if (pts.empty()) continue;
    const bool peer = s.engine != "phys";
    const std::string name = peer ? s.config : s.config + " (" + s.engine + ")";
    for (int front = 0; front < 2; ++front) {
      dat << (block ? "\n\n" : "") << "# " << name << (front ? ": front\n" : ": runs\n");
      for (const SweepPoint* p : pts) {
        if (front && !p->pareto) continue;
        dat << fmt9(p->msMedian) << " " << fmt9(plotted(*p)) << " " << fmt9(*p->error) << " "
            << gpString(budgetText(*p)) << "\n";
      }
      block++;
    }
    const int k = peer ? peers++ : phys++;
    const std::string colour = peer ? kPeerColours[k % std::size(kPeerColours)]
                                    : kPhysColours[k % std::size(kPhysColours)];
    const int pt = peer ? kPeerPointTypes[k % std::size(kPeerPointTypes)]
                        : kPhysPointTypes[k % std::size(kPhysPointTypes)];
    const std::string lc = " lc rgb " + gpString(colour);
    plot << (block > 2 ? ", \\\n     " : "plot ") << gpString(stem + ".dat") << " index "
         << block - 2 << " using 1:2 with points" << lc << " pt " << pt << " ps 1.3 notitle"
         << ", \\\n     '' index " << block - 1 << " using 1:2 with linespoints" << lc << " dt "
         << (peer ? 2 : 1) << " lw 1.5 pt " << pt << " ps 1.3 title " << gpString(s.config)
         << ", \\\n     '' index " << block - 1
         << " using 1:2:4 with labels left offset char 0.6,0.6 font ',8' tc rgb "
         << gpString(colour) << " notitle";
  }

  std::string title = scene;
  if (floor) title += "\n(error <= 0 drawn at " + fmt3(*floor) + ")";
  std::ostringstream gp;
  gp << "# physbench --sweep, scene " << scene << ": run from this directory: gnuplot " << stem
     << ".gp\n"
     << "# ms per step against the error, log scales; lines join each config's front, whose\n"
     << "# points carry their budget (substeps x iterations, or a peer's iterations).\n"
     << "set logscale xy\nset grid\nset format x '%g'\nset format y '%g'\n"
     << "set xlabel 'ms per step (median)'\n"
     << "set ylabel " << gpString(metricText(scene, all.front()->metric)) << "\n"
     << "set title " << gpString(title) << "\n"
     << "set key outside right top title 'line: front'\n"
     << "if (strstrt(GPVAL_TERMINALS, 'pngcairo') > 0) {\n"
     << "  set terminal pngcairo size 1000,650 noenhanced font ',10'\n"
     << "} else {\n"
     << "  set terminal png size 1000,650 noenhanced\n"
     << "}\n"
     << "set output " << gpString(stem + ".png") << "\n"
     << plot.str() << "\n"
     << "set terminal svg size 1000,650 noenhanced font 'sans,12'\n"
     << "set output " << gpString(stem + ".svg") << "\n"
     << "replot\nunset output\n";
  return {dat.str(), gp.str()};
}

/// "soft_step 4x2 (2.1 ms, 0.001)".
std::string pointText(const SweepPoint& p) {
  return runName(p) + " (" + fmt3(p.msMedian) + " ms, " + fmt3(*p.error) + ")";
}

/// A Markdown table cell: no pipes or line breaks.
std::string mdCell(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '|')
      out += "\\|";
    else if (c == '\n' || c == '\r')
      out += ' ';
    else
      out += c;
  }
  return out;
}

/// The reading of one scene: phys's front, then for each peer its points no phys point
/// dominates, or the phys point that dominates its most accurate one.
std::string reading(const std::vector<Series>& series) {
  std::vector<const SweepPoint*> phys;
  for (const Series& s : series) {
    for (const SweepPoint* p : s.points) {
      if (isPhys(*p) && valued(*p)) phys.push_back(p);
    }
  }
  std::ostringstream out;
  std::vector<const SweepPoint*> front;
  for (const SweepPoint* p : phys) {
    if (std::none_of(phys.begin(), phys.end(), [&](auto q) { return dominates(*q, *p); }))
      front.push_back(p);
  }
  std::stable_sort(front.begin(), front.end(), [](auto a, auto b) {
    return std::make_pair(a->msMedian, *a->error) < std::make_pair(b->msMedian, *b->error);
  });
  if (front.empty()) {
    out << "- No phys run has a value.\n";
  } else {
    out << "- Front of the phys runs (no other phys run is as fast and as accurate with one of "
           "the two better), fastest first: ";
    for (size_t i = 0; i < front.size(); ++i) out << (i ? "; " : "") << pointText(*front[i]);
    out << ".\n";
  }
  const SweepPoint* fastest = front.empty() ? nullptr : front.front();

  // Peers in series order, each with its points of every budget.
  std::vector<std::string> peers;
  for (const Series& s : series) {
    if (s.engine != "phys" && std::find(peers.begin(), peers.end(), s.engine) == peers.end())
      peers.push_back(s.engine);
  }
  for (const std::string& peer : peers) {
    std::vector<const SweepPoint*> pts;
    int runs = 0;
    for (const Series& s : series) {
      if (s.engine != peer) continue;
      runs += int(s.points.size());
      for (const SweepPoint* p : s.points) {
        if (valued(*p)) pts.push_back(p);
      }
    }
    if (pts.empty()) {
      out << "- " << peer << ": no run with a value (see the table).\n";
      continue;
    }
    bool allDominated = true;
    for (const SweepPoint* q : pts) {
      if (std::any_of(phys.begin(), phys.end(), [&](auto p) { return dominates(*p, *q); }))
        continue;
      allDominated = false;
      out << "- At " << fmt3(q->msMedian) << " ms/step, " << q->label << " reaches " << q->metric
          << " " << fmt3(*q->error);
      // The most accurate phys point at this cost or less (then the fastest of those).
      const SweepPoint* best = nullptr;
      for (const SweepPoint* p : phys) {
        if (p->msMedian > q->msMedian) continue;
        if (!best || *p->error < *best->error ||
            (*p->error == *best->error && p->msMedian < best->msMedian))
          best = p;
      }
      if (!fastest) {
        out << "; no phys run has a value.\n";
      } else if (!best) {
        out << " where no phys run is as fast (fastest phys: " << runName(*fastest) << " at "
            << fmt3(fastest->msMedian) << " ms, " << fmt3(*fastest->error) << ").\n";
      } else if (*best->error == *q->error) {
        out << ", as does " << runName(*best) << " at the same cost.\n";
      } else {
        out << " where the best phys run at that cost or less has " << fmt3(*best->error) << " ("
            << runName(*best) << " at " << fmt3(best->msMedian) << " ms).\n";
      }
    }
    if (!allDominated) continue;
    // Example: the peer's most accurate point and the most accurate phys point dominating it.
    const SweepPoint* q = *std::min_element(pts.begin(), pts.end(), [](auto a, auto b) {
      return std::make_pair(*a->error, a->msMedian) < std::make_pair(*b->error, b->msMedian);
    });
    const SweepPoint* p = nullptr;
    for (const SweepPoint* c : phys) {
      if (dominates(*c, *q) &&
          (!p || std::make_pair(*c->error, c->msMedian) < std::make_pair(*p->error, p->msMedian)))
        p = c;
    }
    out << "- Every " << peer << " point";
    if (int(pts.size()) < runs) out << " with a value (" << pts.size() << " of " << runs << ")";
    out << " is dominated: e.g. " << runName(*p) << " is "
        << (p->msMedian < q->msMedian ? "faster" : "as fast") << " and "
        << (*p->error < *q->error ? "more accurate" : "as accurate") << " than " << q->label << " ("
        << fmt3(p->msMedian) << " ms vs " << fmt3(q->msMedian) << " ms, " << fmt3(*p->error)
        << " vs " << fmt3(*q->error) << ").\n";
  }
  return out.str();
}

}  // namespace

std::vector<SweepPoint> sweepPoints(const SuiteReport& report) {
  std::vector<SweepPoint> out;
  for (const RunResult& r : report.runs) {
    SweepPoint p;
    p.scene = r.scene;
    p.engine = r.engine;
    p.config = r.config.empty() ? r.preset : r.config;
    p.label = r.preset;
    p.substeps = r.substeps;
    p.iterations = r.iterations;
    p.status = r.status;
    p.metric = r.main.name.empty() ? mainMetricFor(r.scene).name : r.main.name;
    if (ran(p)) {
      p.msMedian = r.metrics.msPerStepMedian;
      p.msP99 = r.metrics.msPerStepP99;
    }
    if (ran(p) && r.status != RunStatus::NaN && r.mainValue && std::isfinite(*r.mainValue))
      p.error = r.mainValue;
    std::vector<std::string> notes;
    if (!r.error.empty()) notes.push_back(r.error);
    if (r.status == RunStatus::NaN && r.nanTime >= 0)
      notes.push_back("at " + fmt3(r.nanTime) + " s");
    for (const CriterionResult& c : r.failed) notes.push_back(c.name + " " + fmtNumber(c.value));
    for (size_t i = 0; i < notes.size(); ++i) p.note += (i ? "; " : "") + notes[i];
    out.push_back(std::move(p));
  }
  for (SweepPoint& p : out) {
    if (!valued(p)) continue;
    p.pareto = std::none_of(out.begin(), out.end(), [&](const SweepPoint& q) {
      return q.scene == p.scene && q.engine == p.engine && q.config == p.config && valued(q) &&
             dominates(q, p);
    });
  }
  return out;
}

std::string writeSweepCsv(const std::vector<SweepPoint>& points, const std::string& path) {
  std::ostringstream out;
  out << "scene,engine,config,label,substeps,iterations,ms_median,ms_p99,metric,error,status,"
         "note,pareto\n";
  for (const SweepPoint& p : points) {
    out << csvField(p.scene) << "," << csvField(p.engine) << "," << csvField(p.config) << ","
        << csvField(p.label) << "," << p.substeps << "," << p.iterations << ","
        << (ran(p) ? fmt9(p.msMedian) : "") << "," << (ran(p) ? fmt9(p.msP99) : "") << ","
        << csvField(p.metric) << "," << (p.error ? fmt9(*p.error) : "") << ","
        << csvField(toString(p.status)) << "," << csvField(p.note) << "," << (p.pareto ? 1 : 0)
        << "\n";
  }
  return writeAtomically(path, out.str());
}

std::string gnuplotVersion() {
  int status = -1;
  std::string out = runCommand("gnuplot --version 2>/dev/null", &status);
  if (status != 0) return {};
  return out.substr(0, out.find_first_of("\r\n"));
}

std::string writeSweepPlots(const std::vector<SweepPoint>& points, const std::string& dir,
                            std::vector<std::string>* files) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return "cannot create " + dir + ": " + ec.message();
  const bool render = !gnuplotVersion().empty();
  for (const std::string& scene : sceneOrder({}, points)) {
    const PlotFiles pf = plotFiles(points, scene);
    if (pf.gp.empty()) continue;
    const std::string base = (std::filesystem::path(dir) / fileStem(scene)).string();
    for (const auto& [ext, text] : {std::pair{".dat", &pf.dat}, std::pair{".gp", &pf.gp}}) {
      std::string err = writeAtomically(base + ext, *text);
      if (!err.empty()) return err;
      files->push_back(base + ext);
    }
    if (!render) continue;
    int status = -1;
    std::string log = runCommand(
        "cd " + shellWord(dir) + " && gnuplot " + shellWord(fileStem(scene) + ".gp") + " 2>&1",
        &status);
    if (status != 0) {
      while (!log.empty() && std::isspace(static_cast<unsigned char>(log.back()))) log.pop_back();
      return "gnuplot failed on " + base + ".gp (exit status " + std::to_string(status) +
             "): " + log;
    }
    files->push_back(base + ".png");
    files->push_back(base + ".svg");
  }
  return {};
}

std::string sweepMarkdown(const SuiteReport& report, const std::vector<SweepPoint>& points,
                          const std::string& plotDir) {
  std::ostringstream md;
  md << "Each run is a point: median wall time per step against the scene's main error "
        "metric, lower is better on both. \"front\": no other run of the same config is as "
        "fast and as accurate with one of the two better. Runs that went NaN, could not be "
        "executed or cannot run in a peer have no value: listed, not plotted. Plots: log "
        "scales; an error <= 0 is drawn at a floor named in the plot's title.\n";
  const std::string prefix = plotDir.empty() || plotDir.ends_with('/') ? plotDir : plotDir + "/";
  for (const std::string& scene : sceneOrder(report.scenes, points)) {
    const std::vector<Series> series = seriesOf(points, scene);
    md << "\n### " << scene;
    auto secs = report.sceneSeconds.find(scene);
    if (secs != report.sceneSeconds.end()) md << " (" << fmt3(secs->second) << " s simulated)";
    md << "\n\n";
    if (std::any_of(points.begin(), points.end(),
                    [&](const SweepPoint& p) { return p.scene == scene && valued(p); }))
      md << "![" << scene << "](" << prefix << fileStem(scene) << ".svg)\n\n";
    md << "| config | budget | ms/step | " << mdCell(metricText(scene, series[0].points[0]->metric))
       << " | status | front |\n|---|---|---|---|---|---|\n";
    for (const Series& s : series) {
      for (const SweepPoint* p : s.points) {
        md << "| " << mdCell(p->config) << " | " << budgetText(*p)
           << (ownBudget(*p) && budgetText(*p) != "default" ? " (preset's own)" : "") << " | "
           << (ran(*p) ? fmt3(p->msMedian) : "-") << " | " << (p->error ? fmt3(*p->error) : "-")
           << " | " << toString(p->status)
           << (p->note.empty()               ? ""
               : p->status == RunStatus::NaN ? " "
                                             : ": ")
           << mdCell(p->note) << " | " << (p->pareto ? "yes" : "") << " |\n";
      }
    }
    md << "\nReading:\n\n" << reading(series);
  }
  return md.str();
}

}  // namespace phys::bench
