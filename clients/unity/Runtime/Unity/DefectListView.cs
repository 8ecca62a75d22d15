using System;
using System.Collections.Generic;
using System.Linq;
using UnityEngine;
using UnityEngine.UI;

namespace Vista.Client.Unity
{
    /// <summary>
    /// The floating defect window: filter menus (type, status, severity), a sort menu, one
    /// button per defect with its line of text (<see cref="DefectListModel.Line"/>), and a status
    /// line (online or not, judgments waiting). Picking a row selects the defect: the
    /// <see cref="JudgmentPanel"/> shows it and its marker in the scene is enlarged. A tap on a
    /// marker in the scene can select it through <see cref="Select"/> (see <see cref="DefectHandle"/>).
    /// </summary>
    public sealed class DefectListView : MonoBehaviour
    {
        const string All = "all";

        [SerializeField] VistaClientBehaviour client;
        [SerializeField] SceneLoader sceneLoader;
        [SerializeField] JudgmentPanel judgmentPanel;
        [SerializeField] RectTransform rowContainer;
        [Tooltip("A Button with a Text child; one is made per visible defect.")]
        [SerializeField] Button rowPrefab;
        [SerializeField] Dropdown typeFilter;
        [SerializeField] Dropdown statusFilter;
        [SerializeField] Dropdown severityFilter;
        [SerializeField] Dropdown sortBy;
        [SerializeField] Toggle descending;
        [SerializeField] Text statusLine;

        readonly List<Button> rows = new List<Button>();
        DefectListModel model;

        void Start()
        {
            model = new DefectListModel(client.Sync);
            sortBy.ClearOptions();
            sortBy.AddOptions(Enum.GetNames(typeof(DefectSortKey)).ToList());
            typeFilter.onValueChanged.AddListener(_ => ApplyControls());
            statusFilter.onValueChanged.AddListener(_ => ApplyControls());
            severityFilter.onValueChanged.AddListener(_ => ApplyControls());
            sortBy.onValueChanged.AddListener(_ => ApplyControls());
            descending.onValueChanged.AddListener(_ => ApplyControls());
            client.StatusChanged += Refresh;
            sceneLoader.Loaded += Highlight;
            Refresh();
        }

        void OnDestroy()
        {
            if (client != null)
            {
                client.StatusChanged -= Refresh;
            }
            if (sceneLoader != null)
            {
                sceneLoader.Loaded -= Highlight;
            }
        }

        /// <summary>Selects a defect (null: none) in the list, the panel and the scene.</summary>
        public void Select(long? defectId)
        {
            model.SelectedDefectId = defectId;
            judgmentPanel.Show(defectId);
            Highlight();
            Refresh();
        }

        /// <summary>Selects the next visible defect (for a voice command or a button).</summary>
        public void SelectNext() => Select(model.Step(1));

        /// <summary>Selects the previous visible defect.</summary>
        public void SelectPrevious() => Select(model.Step(-1));

        void ApplyControls()
        {
            model.TypeFilter = Chosen(typeFilter);
            model.StatusFilter = Chosen(statusFilter);
            model.SeverityFilter = Chosen(severityFilter);
            model.SortBy = (DefectSortKey)Enum.Parse(typeof(DefectSortKey), sortBy.options[sortBy.value].text);
            model.Descending = descending.isOn;
            Refresh();
        }

        void Highlight()
        {
            sceneLoader.Highlight(model.SelectedDefectId);
        }

        void Refresh()
        {
            Fill(typeFilter, model.Choices(d => d.Type));
            Fill(statusFilter, model.Choices(d => d.Status));
            Fill(severityFilter, model.Choices(d => d.Severity));
            List<Defect> visible = model.Rows();
            while (rows.Count < visible.Count)
            {
                rows.Add(Instantiate(rowPrefab, rowContainer));
            }
            for (int i = 0; i < rows.Count; i++)
            {
                bool used = i < visible.Count;
                rows[i].gameObject.SetActive(used);
                rows[i].onClick.RemoveAllListeners();
                if (!used)
                {
                    continue;
                }
                Defect defect = visible[i];
                string marker = defect.Id == model.SelectedDefectId ? "▶ " : "";
                rows[i].GetComponentInChildren<Text>().text = marker + model.Line(defect);
                rows[i].onClick.AddListener(() => Select(defect.Id));
            }
            int waiting = client.Sync.Outbox.Count;
            string connection = client.Online ? "online" : "offline";
            statusLine.text = $"{visible.Count} of {client.Sync.Defects.Count} defects · {connection} · "
                + $"{waiting} judgment(s) waiting" + (client.LastError == null ? "" : $" · {client.LastError}");
        }

        /// <summary>Sets a filter menu's choices ("all" first), keeping the current choice even
        /// when no defect has that value any more (the list then shows none).</summary>
        static void Fill(Dropdown menu, List<string> choices)
        {
            string current = menu.options.Count > 0 ? menu.options[menu.value].text : All;
            var options = new List<string> { All };
            options.AddRange(choices);
            if (!options.Contains(current))
            {
                options.Add(current);
            }
            menu.ClearOptions();
            menu.AddOptions(options);
            menu.SetValueWithoutNotify(options.IndexOf(current));
        }

        static string Chosen(Dropdown menu)
        {
            string text = menu.options[menu.value].text;
            return text == All ? null : text;
        }
    }
}
