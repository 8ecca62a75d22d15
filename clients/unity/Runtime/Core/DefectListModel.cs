using System;
using System.Collections.Generic;
using System.Globalization;
using System.Linq;

namespace Vista.Client
{
    /// <summary>What the defect list can be sorted by.</summary>
    public enum DefectSortKey
    {
        /// <summary>Defect id (the order they were found in).</summary>
        Id,
        /// <summary>Type name, alphabetically.</summary>
        Type,
        /// <summary>Measured value; defects without one last.</summary>
        Value,
        /// <summary>Workflow status, alphabetically.</summary>
        Status,
        /// <summary>Share of reviewers that agree; unjudged defects first (they need eyes).</summary>
        Agreement,
        /// <summary>Majority verdict, in the order of <see cref="Verdicts.All"/>; no majority first.</summary>
        Majority,
    }

    /// <summary>
    /// The floating defect window without its widgets: which defects show (filters), in which
    /// order, which one is selected, and the line of text each one gets, e.g.
    /// <c>gap 1.23 mm &gt; 1.00 mm · open · 2/3 confirmed</c>.
    /// </summary>
    public sealed class DefectListModel
    {
        readonly SyncClient source;

        /// <summary>A list over the copy kept by <paramref name="source"/>.</summary>
        public DefectListModel(SyncClient source)
        {
            if (source == null)
            {
                throw new ArgumentNullException("source");
            }
            this.source = source;
            SortBy = DefectSortKey.Id;
        }

        /// <summary>Only defects of this type (null: all types).</summary>
        public string TypeFilter { get; set; }

        /// <summary>Only defects in this status (null: all).</summary>
        public string StatusFilter { get; set; }

        /// <summary>Only defects of this severity (null: all).</summary>
        public string SeverityFilter { get; set; }

        /// <summary>The sort order; ties go by id.</summary>
        public DefectSortKey SortBy { get; set; }

        /// <summary>Reverse the sort order (ties still by ascending id).</summary>
        public bool Descending { get; set; }

        /// <summary>The selected defect's id, or null.</summary>
        public long? SelectedDefectId { get; set; }

        /// <summary>The selected defect, or null when none is selected or it is gone.</summary>
        public Defect Selected
        {
            get
            {
                Defect defect;
                return SelectedDefectId.HasValue && source.Defects.TryGetValue(SelectedDefectId.Value, out defect)
                    ? defect : null;
            }
        }

        /// <summary>The defects that pass the filters, in the chosen order.</summary>
        public List<Defect> Rows()
        {
            List<Defect> rows = source.Defects.Values
                .Where(d => (TypeFilter == null || d.Type == TypeFilter)
                    && (StatusFilter == null || d.Status == StatusFilter)
                    && (SeverityFilter == null || d.Severity == SeverityFilter))
                .ToList();
            rows.Sort((a, b) =>
            {
                int order = Compare(a, b);
                if (Descending)
                {
                    order = -order;
                }
                return order != 0 ? order : a.Id.CompareTo(b.Id);
            });
            return rows;
        }

        /// <summary>The distinct values of a field among all defects, sorted (for filter menus).</summary>
        public List<string> Choices(Func<Defect, string> field)
        {
            return source.Defects.Values.Select(field).Where(v => v != null).Distinct()
                .OrderBy(v => v, StringComparer.Ordinal).ToList();
        }

        /// <summary>Selects the next (or, with −1, previous) visible row, wrapping around;
        /// returns the selected id (null when no row shows).</summary>
        public long? Step(int direction)
        {
            List<Defect> rows = Rows();
            if (rows.Count == 0)
            {
                SelectedDefectId = null;
                return null;
            }
            int at = rows.FindIndex(d => d.Id == SelectedDefectId);
            int next = at < 0 ? 0 : ((at + Math.Sign(direction)) % rows.Count + rows.Count) % rows.Count;
            SelectedDefectId = rows[next].Id;
            return SelectedDefectId;
        }

        /// <summary>One line for a defect: type, value against tolerance, status and what the
        /// reviewers think.</summary>
        public string Line(Defect defect)
        {
            var parts = new List<string> { Measurement(defect), defect.Status, Opinion(source.ConsensusOf(defect.Id)) };
            return string.Join(" · ", parts.ToArray());
        }

        static string Measurement(Defect defect)
        {
            if (!defect.Value.HasValue)
            {
                return defect.Type;
            }
            string text = defect.Type + " " + Quantity(defect.Value.Value, defect.Unit);
            if (defect.Tolerance.HasValue)
            {
                int side = defect.Value.Value.CompareTo(defect.Tolerance.Value);
                string relation = side > 0 ? ">" : side < 0 ? "<" : "=";
                text += " " + relation + " " + Quantity(defect.Tolerance.Value, defect.Unit);
            }
            return text;
        }

        static string Quantity(double value, string unit)
        {
            string number = value.ToString("0.00", CultureInfo.InvariantCulture);
            return unit == "delta_e" ? "ΔE " + number : number + " " + unit;
        }

        static string Opinion(Consensus consensus)
        {
            if (consensus == null || consensus.Total == 0)
            {
                return "not judged";
            }
            if (consensus.Majority == null)
            {
                return "split (" + consensus.Total + " judgments)";
            }
            string text = consensus.CountOf(consensus.Majority) + "/" + consensus.Total + " " + consensus.Majority;
            return consensus.NeedsReview ? text + ", needs review" : text;
        }

        int Compare(Defect a, Defect b)
        {
            switch (SortBy)
            {
                case DefectSortKey.Type:
                    return string.CompareOrdinal(a.Type, b.Type);
                case DefectSortKey.Value:
                    // Values in different units do not compare: grouped by unit, then by value.
                    int units = string.CompareOrdinal(a.Unit, b.Unit);
                    return units != 0 ? units : CompareValues(a.Value, b.Value);
                case DefectSortKey.Status:
                    return string.CompareOrdinal(a.Status, b.Status);
                case DefectSortKey.Agreement:
                    return AgreementRank(a).CompareTo(AgreementRank(b));
                case DefectSortKey.Majority:
                    return MajorityRank(a).CompareTo(MajorityRank(b));
                default:
                    return a.Id.CompareTo(b.Id);
            }
        }

        static int CompareValues(double? a, double? b)
        {
            if (a.HasValue && b.HasValue)
            {
                return a.Value.CompareTo(b.Value);
            }
            return a.HasValue ? -1 : b.HasValue ? 1 : 0;
        }

        double AgreementRank(Defect defect)
        {
            Consensus consensus = source.ConsensusOf(defect.Id);
            return consensus == null || consensus.Total == 0 ? -1.0 : consensus.Agreement;
        }

        int MajorityRank(Defect defect)
        {
            Consensus consensus = source.ConsensusOf(defect.Id);
            return consensus == null || consensus.Majority == null ? -1 : Array.IndexOf(Verdicts.All, consensus.Majority);
        }
    }
}
